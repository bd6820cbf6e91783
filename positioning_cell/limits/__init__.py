"""The operator's limits of the positioner, pure library (no ROS): the validity bitmask of a
check and its margins (:mod:`.validity`), the factory, machine and user limit boxes in pose6
(:mod:`.boxes`), the live range of each user axis with the others held (:mod:`.axis_ranges`),
the operator's speeds and accelerations (:mod:`.speed`) and the jog of one actuator, outside
the kinematics (:mod:`.jog`).

A pose6 is (tx, ty, tz m, rx, ry, rz rad) with R = Rz(rz)·Ry(ry)·Rx(rx) (scipy's extrinsic
'xyz' Euler angles); every value is SI, the texts for people are in mm and degrees.
"""
