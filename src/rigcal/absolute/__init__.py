"""The body frame from an external measurement (wheels, ground plane, markers on the vehicle).

Relative calibration gives every sensor's pose in a reference sensor's frame; this package ties
those poses to the vehicle body frame (``T_body_sensor``), which is what a URDF or a TF tree
needs (see :mod:`rigcal.io.urdf` and :mod:`rigcal.io.tf_export`).
"""
