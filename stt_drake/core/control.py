"""Closed-form funnel controller of Sec. 4 for an N-th order pure-feedback system.

Stage 1 (ball funnel around the tube): e₁ = ‖x₁ − c‖/r, ρ₁ = ln((1 + e₁)/(1 − e₁)),
r₂ = −κ₁ ρ₁ (x₁ − c)  (Eq. (20a)).
Stage k ≥ 2 (box funnel around the reference r_k): γ_k(t) = (p_k − q_k)e^{−μ_k t} + q_k,
e_k = (x_k − r_k)/γ_k, ρ_k = ln((1 + e_k)/(1 − e_k)), ξ_k = 4 γ_k⁻¹ (1 − e_k²)⁻¹
(element-wise, Eqs. (19a)–(19c)), r_{k+1} = −κ_k ξ_k ρ_k; the control is u = r_{N+1}.

The law reads measured states only: no model parameter of the plant. It never returns
NaN or inf: a normalised error at or beyond its funnel boundary is saturated just inside
(|e| ≤ 1 − 1e-9, so ρ ≤ 21.4) and the invariant monitor reports the violation.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from stt_drake.core import backend
from stt_drake.core.rules import check_box_funnel, check_kappa, checked_by

#: Largest normalised error the law uses; errors beyond it are saturated here.
ERROR_SATURATION = 1.0 - 1e-9


def transformed_error(normalized_error: np.ndarray) -> np.ndarray:
    """ρ = ln((1 + e)/(1 − e)) = 2 atanh(e), with e saturated to ±ERROR_SATURATION."""
    return 2.0 * np.arctanh(np.clip(normalized_error, -ERROR_SATURATION, ERROR_SATURATION))


@dataclass(frozen=True)
class BoxFunnel:
    """γ(t) = (start − end)e^{−rate·t} + end per component (stage k ≥ 2 of Sec. 4).

    Attributes:
        start: (n,) or scalar p > 0, the half-width at t = 0; must contain |x_k(0) − r_k(0)|.
        end: (n,) or scalar q ∈ (0, p), the final half-width.
        rate: (n,) or scalar μ ≥ 0, the decay rate (1/s).

    All finite; checked when made (:func:`stt_drake.core.rules.check_box_funnel`).
    """

    start: np.ndarray | float
    end: np.ndarray | float
    rate: np.ndarray | float

    def __post_init__(self) -> None:
        with checked_by("BoxFunnel"):
            check_box_funnel(self.start, self.end, self.rate)

    def width(self, t: float) -> np.ndarray:
        start = np.asarray(self.start, dtype=float)
        end = np.asarray(self.end, dtype=float)
        return (start - end) * np.exp(-np.asarray(self.rate, dtype=float) * t) + end


def box_funnel_stage(
    t: float, state: np.ndarray, reference: np.ndarray, funnel: BoxFunnel, kappa: float
) -> tuple[np.ndarray, np.ndarray]:
    """One stage k ≥ 2 of Sec. 4 (Eq. (19)): keep x_k inside the box funnel around r_k.

    e_k = (x_k − r_k)/γ_k(t), ρ_k = ln((1 + e_k)/(1 − e_k)), ξ_k = 4 γ_k⁻¹ (1 − e_k²)⁻¹
    (element-wise), and the next reference r_{k+1} = −κ_k ξ_k ρ_k.

    Returns:
        (r_{k+1}, e_k): the next stage's reference (the control at the last stage) and the
        normalised error before saturation (|e_k| < 1 inside the funnel).
    """
    gamma = funnel.width(t)
    e = (state - reference) / gamma
    saturated = np.clip(e, -ERROR_SATURATION, ERROR_SATURATION)
    xi = 4.0 / (gamma * (1.0 - saturated * saturated))
    return -kappa * xi * transformed_error(e), e


@dataclass(frozen=True)
class ControlEvaluation:
    """One evaluation of the funnel law.

    Attributes:
        control: (n,) the input u = r_{N+1}.
        normalized_errors: list of the N normalised errors: e₁ (scalar, as a (1,) array)
            and e_k (n,) for k ≥ 2, before saturation. |e| < 1 means inside the funnel.
    """

    control: np.ndarray
    normalized_errors: list[np.ndarray] = field(default_factory=list)


@dataclass(frozen=True)
class FunnelController:
    """The controller of Theorem 4.1 for N = len(kappa) stages.

    Attributes:
        kappa: κ_1..κ_N (> 0, finite; :func:`stt_drake.core.rules.check_kappa`).
        funnels: the N − 1 box funnels of stages 2..N (each checked when made).
    """

    kappa: Sequence[float]
    funnels: Sequence[BoxFunnel] = ()

    def __post_init__(self) -> None:
        with checked_by("FunnelController"):
            check_kappa(self.kappa)
        if len(self.funnels) != len(self.kappa) - 1:
            raise ValueError(
                f"funnels: {len(self.kappa)} stages need {len(self.kappa) - 1} box funnels, "
                f"got {len(self.funnels)}"
            )

    @property
    def stages(self) -> int:
        return len(self.kappa)

    @cached_property
    def _kernel_arguments(self) -> dict[int, tuple[np.ndarray | float, ...]]:
        """Per dimension n: the compiled laws' last arguments, κ (N,), the funnels' p, q, μ
        as (N − 1, n) float arrays and ERROR_SATURATION (:meth:`compiled_arguments`)."""
        return {}

    def compiled_arguments(self, dimension: int) -> tuple[np.ndarray | float, ...]:
        """The compiled laws' last arguments for output dimension n = `dimension`: κ (N,),
        the funnels' p, q, μ as (N − 1, n) arrays and ERROR_SATURATION (made once per n)."""
        arguments = self._kernel_arguments.get(dimension)
        if arguments is None:
            shape = (len(self.funnels), dimension)

            def stacked(name: str) -> np.ndarray:
                rows = [
                    np.broadcast_to(np.asarray(getattr(f, name), float), shape[1:])
                    for f in self.funnels
                ]
                return np.array(rows, dtype=float).reshape(shape)

            kappa = np.array(self.kappa, dtype=float)
            arguments = (kappa, stacked("start"), stacked("end"), stacked("rate"), ERROR_SATURATION)
            self._kernel_arguments[dimension] = arguments
        return arguments

    @cached_property
    def _packed_laws(self) -> dict[int, np.ndarray]:
        """Per dimension n: :meth:`packed_law`."""
        return {}

    def packed_law(self, dimension: int) -> np.ndarray:
        """The compiled funnel_control_packed's `law` for output dimension n = `dimension`:
        [ERROR_SATURATION, κ (N,), p, q, μ ((N − 1)·n each, row-major)], the
        :meth:`compiled_arguments` in one array (made once per n)."""
        law = self._packed_laws.get(dimension)
        if law is None:
            kappa, start, end, rate, saturation = self.compiled_arguments(dimension)
            law = np.concatenate([[saturation], kappa, start.ravel(), end.ravel(), rate.ravel()])
            self._packed_laws[dimension] = law
        return law

    @cached_property
    def _kernel(self) -> Callable[..., tuple[np.ndarray, np.ndarray, bool]] | None:
        """The compiled funnel_control, looked up once (read while it is selected): the
        lookup costs a tenth of an evaluation."""
        return backend.compiled("funnel_control")

    @cached_property
    def _packed_kernel(self) -> Callable[..., np.ndarray | None] | None:
        """The compiled funnel_control_packed, looked up once (read while it is selected)."""
        return backend.compiled("funnel_control_packed")

    def control_from_tube(self, t: float, states: np.ndarray, tube: np.ndarray) -> np.ndarray:
        """Only the control u, from stacked states and the `tube` port vector [c, r]: the
        Drake system's hot path (no ControlEvaluation built). Same value as
        ``evaluate(t, states, tube[:-1], tube[-1]).control``."""
        kernel = self._packed_kernel if backend.using_compiled() else None
        if kernel is not None:
            control = kernel(
                float(t),
                np.asarray(states, dtype=float),
                np.asarray(tube, dtype=float),
                self.packed_law(len(tube) - 1),
            )
            if control is not None:  # None: an input not finite, or lengths that do not fit
                return control
        return self.evaluate(t, states, tube[:-1], tube[-1]).control

    def evaluate(
        self, t: float, states: np.ndarray, center: np.ndarray, radius: float
    ) -> ControlEvaluation:
        """Control at time t for stacked states (N, n) = [x_1; ...; x_N] and tube (c, r).

        One call of the compiled :func:`stt_drake.core._kernels.funnel_control` (unless the numpy
        path is selected, see :mod:`stt_drake.core.backend`); non-finite inputs go on to the
        reference path below, which names them in its ValueError.
        """
        kernel = self._kernel if backend.using_compiled() else None
        if kernel is not None:
            center = np.asarray(center, dtype=float)
            flat = np.asarray(states, dtype=float).reshape(-1)
            n = center.shape[0]
            if flat.shape[0] == self.stages * n:
                control, errors, finite = kernel(
                    float(t), flat, center, float(radius), *self.compiled_arguments(n)
                )
                if finite:
                    stages = [errors[1 + k * n : 1 + (k + 1) * n] for k in range(self.stages - 1)]
                    return ControlEvaluation(control, [errors[:1], *stages])
        states = np.asarray(states, dtype=float).reshape(self.stages, -1)
        if not (
            np.all(np.isfinite(states))
            and np.all(np.isfinite(center))
            and np.isfinite(radius)
            and np.isfinite(t)
        ):
            raise ValueError(
                f"controller input is not finite: t={t}, states={states}, center={center}, "
                f"radius={radius}"
            )
        offset = states[0] - center
        distance = float(np.linalg.norm(offset))
        e1 = distance / radius if radius > 0.0 else np.inf
        reference = -self.kappa[0] * transformed_error(np.array(e1)) * offset
        errors = [np.array([e1])]
        for kappa, funnel, state in zip(self.kappa[1:], self.funnels, states[1:], strict=True):
            reference, e = box_funnel_stage(t, state, reference, funnel, kappa)
            errors.append(e)
        return ControlEvaluation(control=reference, normalized_errors=errors)
