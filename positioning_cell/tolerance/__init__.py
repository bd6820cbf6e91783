"""Tolerance analysis of a mechanism as vector loops (seed 004), the general engine: pure
numpy / scipy / numba.

- :mod:`.expressions`: affine expressions of named symbols with units (a vector's length and
  angle, a scalar loop equation), SI inside.
- :mod:`.model`: the mechanism as data (sources, inputs, unknowns, gap connectors with seed
  004's orientation rules, closed and open loops, requirements) and its YAML loader.
- :mod:`.loops`: the loop equations as arrays, their exact and finite-difference derivatives,
  the nominal solve and the first-order model A, U, C, D, T (seed 004 eqs. 5-14); the
  trigonometric normal form the Monte Carlo kernel interprets.
- :mod:`.linear`: T = C − D·U⁻¹·A (eq. 14), a singular or ill-conditioned U refused with the
  dependent unknowns and equations named.
- :mod:`.stackup`: worst case (eq. 15), root-sum-square, each source's contribution (Pareto),
  the yield against a requirement with its confidence interval.
- :mod:`.sampling`: the sources' laws (truncated normal, uniform).
- :mod:`.montecarlo`: the nonlinear loop closure per sample in one compiled kernel for every
  mechanism; a per-sample ``scipy.optimize.root`` reference.
- :mod:`.analysis`: the whole analysis of one mechanism; :mod:`.report`: Markdown, JSON and the
  figures (``tolerance_analysis MECH.yaml --out DIR``).
- :mod:`.seed004`: seed 004 §4's printed matrices and figures, checked.
"""
