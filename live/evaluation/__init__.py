"""Accuracy of the skeleton stage and of retargeting against ground truth (``livecap eval``)."""
