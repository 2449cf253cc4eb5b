"""Kinematics experiments (thesis chapter 2): the learning benchmark of
``mcpilco-bench-kinematics`` (:mod:`.bench`, :mod:`.parts`, :mod:`.report`), the marker
detection benchmark (:mod:`.marker_detection`), MC-PILCO reaching through the learned
kinematics (:mod:`.reaching`) and the camera robot's trajectories (:mod:`.trajectories`)."""
