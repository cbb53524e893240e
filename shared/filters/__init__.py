"""The filter toolkit: one small module per building block, FilterPy-style, in one notation.

Every estimator writes its filter from these blocks (the forms each keeps on purpose are listed in
docs/architecture.md). Each module states its maths in its docstring; every function works on one estimate or on a
batch (leading dimensions), and performs the floating-point operations of the code it replaced, in the same order,
so that moving an estimator onto the toolkit leaves its outputs bit-identical. ``tests/test_filters_*.py`` pin the
blocks to FilterPy (``filterpy.kalman``, ``filterpy.monte_carlo``).

Notation (FilterPy's), with the symbols of each estimator's paper mapped to it:

=====  ==========================================  ======================================================
x      state mean                                  lbl_nav X, rd_nav z (EKF), pcl_tracker x_a / x_b, attitude alpha
P      state covariance                            lbl_nav P, rd_nav Pz / Q_k (PF cloud, Eq. 7), attitude R_alpha / R_n
F      state transition                            lbl_nav Phi, pcl_tracker F, attitude B
Q      process-noise covariance                    lbl_nav Q, rd_nav Q (drift model), W (DR error states), attitude M
H      measurement Jacobian / matrix               every paper: H
R      measurement-noise covariance                pcl_tracker R_a / R_plot, rd_nav R, attitude R_z
z      measurement                                 lbl_nav Y, rd_nav d, pcl_tracker z_b
y      innovation z - h(x)                         lbl_nav / pcl_tracker / rd_nav / attitude nu or e, terrain_nav y_ij
S      innovation covariance H P H^T + R           every paper: S
K      gain P H^T S^-1                             every paper: K
=====  ==========================================  ======================================================

Modules: :mod:`.kalman` (predict, update in standard and Joseph form, NIS and log-likelihood),
:mod:`.unscented` (sigma points, unscented and first-order transforms), :mod:`.covariance` (symmetrise,
robust Cholesky, positive-definiteness), :mod:`.angles` (wrapping), :mod:`.gauss_markov` (first-order
Gauss-Markov discretisation and paths), :mod:`.resampling` (particle resampling, effective sample size).
"""
