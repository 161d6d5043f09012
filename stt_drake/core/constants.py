"""Numeric constants shared by the numpy reference and the compiled (numba) kernels.

Each constant is defined here once; both paths import it (numba freezes a module global
into the compiled code when it compiles, and :mod:`stt_drake.core.backend` keys numba's
on-disk cache on this file's source, so a changed value is recompiled, never loaded stale).
Pure Python: importing this module imports nothing.

Names follow the paper's notation where one applies (paper Sec. 3: q_j of Eq. (5), the
quantile distance d̂_j of Eq. (8), the centre law ċ of Eq. (4), the soft-min radius of
Eq. (14)).
"""

from __future__ import annotations

# --------------------------------------------------------------------------- tube law
#: Width of the boundary layer above each ε level set, as a share of p_d − ε
#: (dimensionless): obstacle j's layer weight is w_j = clip(1 − (q_j − ε_j)/(BOUNDARY_LAYER·
#: (p_d_j − ε_j)), 0, 1), the share of the escape velocity in ċ (Eq. (4) blended; the
#: module docstring of :mod:`stt_drake.core.tube`, "Bounded centre, boundary layer and
#: recovery").
BOUNDARY_LAYER = 0.1

#: Largest change of any boundary-layer weight w_j in one sub-step of the fixed-rate
#: update (dimensionless; :meth:`stt_drake.core.tube.TubeLaw.advance`): the explicit
#: sub-steps resolve the layer.
LAYER_STEP = 0.25

#: A chosen circulation axis ω (3D) is used for the null-space direction v_j ⟂ m_j of
#: Eq. (4) while |ω × m̂_j| exceeds this sine (dimensionless); nearer to parallel, the
#: goal-based rule takes over (:func:`stt_drake.core.circulation.null_space_direction`).
CIRCULATION_MIN_SINE = 1e-3

# --------------------------------------------------------------------------- noncentral chi
#: Φ⁻¹(2⁻⁵⁴) = −8.2924 (dimensionless, in units of σ): for b − a at or below this, the
#: noncentral chi survival function of q_j (Eq. (5)) is 1 in double precision, since
#: 1 − sf ≤ Φ(b − a) ≤ 2⁻⁵⁴ (‖Z‖ ≥ Z·e). The literal is the double nearest to
#: ``scipy.special.ndtri(2.0**-54)`` (tests/core/test_constants.py checks it).
SF_IS_ONE_BELOW = -8.292361075813597

#: A point farther than r + HIT_NEGLIGIBLE_SIGMAS·σ_max from a Gaussian centre μ (covariance
#: Σ, σ_max² = λ_max(Σ); dimensionless, in units of σ_max) lies in the ball of radius r
#: around the random centre with probability at most P(χ²_n > 81), since
#: ‖O − μ‖² ≤ σ_max²‖Z‖² with Z ~ N(0, I_n): 1.9e-17 for n = 3 and less for n < 3, below
#: 2⁻⁵⁴ (half the spacing of doubles just below 1), so the avoid probability is 1.0 in
#: double precision (tests/core/test_constants.py checks the tail with scipy).
HIT_NEGLIGIBLE_SIGMAS = 9.0

#: The compiled quantile of the noncentral chi (d̂_j of Eq. (8)): Halley iterations stop
#: when the last step is below this fraction of s (relative, dimensionless).
CHI_QUANTILE_RTOL = 1e-14

#: Largest number of those quantile iterations (the bracket halves at least every other one).
CHI_QUANTILE_MAX_ITERATIONS = 200

# --------------------------------------------------------------------------- full covariance
# The saddle-point contour integration of P(‖x − O‖ < R), O ~ N(μ, Σ)
# (:mod:`stt_drake.core.anisotropic`, compiled in :mod:`stt_drake.core._anisotropic`): the
# contour is traversed with a parameter u, trapezoid step h in u, nodes u_k = (k − ½)h,
# mapped to τ = u + γu³ and stopped once τ² > PATH_END.

#: Trapezoid step h of the contour parameter u (dimensionless).
PATH_STEP = 0.175

#: Stretch γ of τ = u + γu³ (dimensionless): nodes sparser where the weight e^{−τ²} is small.
PATH_STRETCH = 0.03

#: The contour stops once τ² exceeds this (dimensionless): the rest is below e^{−30}.
PATH_END = 30.0

#: Bend β of the contour: Im ψ = −β τ² tanh(τ/τ_c) along it (dimensionless).
PATH_BEND = 0.6

#: Scale τ_c of that bend (dimensionless).
PATH_BEND_SCALE = 1.0

#: The iteration at a contour node stops after a step u ≤ this fraction of |δ|
#: (dimensionless): the step's error is of order u⁴ < 2e-15.
STEP_ACCEPT = 2e-4

#: Largest number of Newton iterations at one contour node.
NEWTON_MAX_ITERATIONS = 60

#: Largest number of saddle-point iterations.
SADDLE_MAX_ITERATIONS = 200

#: The full-covariance quantile radius (d̂_j of Eq. (8) for O_j ~ N(μ_j, Σ_j)) stops once a
#: step is below this fraction of R² (relative, dimensionless).
ANISOTROPIC_QUANTILE_RTOL = 1e-5

#: Largest number of iterations of that quantile.
ANISOTROPIC_QUANTILE_MAX_ITERATIONS = 60

#: A full covariance Σ is σ²I to rounding, and the tube law takes the noncentral χ law of
#: Proposition 3.1 with σ² = tr Σ/n instead of the contour integral, when every entry of
#: Σ − σ²I is within this share of Σ's largest diagonal entry (dimensionless). Then
#: ‖Σ/σ² − I‖_F ≤ n·ISOTROPIC_RTOL/(1 − ISOTROPIC_RTOL), so by the total-variation bound
#: TV(N(μ, Σ₁), N(μ, Σ₂)) ≤ (3/2)‖Σ₁^{-1/2}Σ₂Σ₁^{-1/2} − I‖_F (Devroye, Mehrabian & Reddad
#: 2018) every probability the law reads moves by less than 5e-12 (n ≤ 3). A Kalman
#: tracker with isotropic noises keeps its position covariance σ²I to ~1e-15 (rounding).
ISOTROPIC_RTOL = 1e-12

#: Below this |z| the saddle-point value uses the series of log(1 − z) + z/(1 − z)
#: (dimensionless).
SERIES_BELOW = 0.1

#: e^{Φ̂} underflows to 0 below this exponent Φ̂ (and erfc(√−Φ̂) too): the small tail is
#: exactly 0 (dimensionless).
UNDERFLOW_EXPONENT = -745.0
