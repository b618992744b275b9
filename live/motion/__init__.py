"""Motion clips: any rig mapped onto the 22 canonical joints, clip cleaning."""
