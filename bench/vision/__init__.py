"""The in-situ vision pipeline (thesis chapter 3): features, triangulation, absolute orientation, RANSAC.

Pipeline side: numpy / scipy / OpenCV only; never imports the simulator, the scenario runner or a dataset's truth.
"""
