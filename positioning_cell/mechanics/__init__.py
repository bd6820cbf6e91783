"""Mechanics of parallel mechanisms: screw theory and mobility (:mod:`.screw`, seed 001),
singularity of the wrench system (:mod:`.singularity`), statics and compliance
(:mod:`.statics`, seed 002), over-constrained limb forces (:mod:`.overconstrained`), inverse
dynamics (:mod:`.dynamics`)."""
