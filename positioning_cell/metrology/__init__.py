"""Measuring the platform with a laser tracker, as the cell knows it: the instrument and its
accuracy (:mod:`.instrument`), the targets on the platform (:mod:`.targets`), and the robust
rigid fit of the pose with its covariance (:mod:`.fit`)."""
