"""Mechanics of parallel mechanisms: screw theory and mobility (:mod:`.screw`, seed 001),
singularity of the wrench system (:mod:`.singularity`), statics and compliance
(:mod:`.statics`, seed 002), over-constrained limb forces in space or in the plane
(:mod:`.overconstrained`, seed 002 §3), seed 002's planar 2-DOF over-constrained mechanism
(:mod:`.planar_parallel`), inverse dynamics (:mod:`.dynamics`)."""
