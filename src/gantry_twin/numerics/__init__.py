"""The numeric toolbox of the per-sample kernels: numba compilation and its cache (:mod:`.jit`), the C maths
library the compiled and reference backends share (:mod:`.libm`), small fixed-size linear algebra
(:mod:`.linalg`) and the estimator's filters, least squares and projections (:mod:`.estimation`, eq. 9, 16,
25-28 of docs/equations.md). Imports nothing of the package but the root's settings and theta."""
