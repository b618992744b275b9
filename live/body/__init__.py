"""Bodies and avatars: the body library, linear blend skinning, avatars from meshes, the skinning field."""
