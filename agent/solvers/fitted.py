"""The fitted model of one analysis: the weighted fit of Δτ = Y·θ made once and handed to every consumer.

Modelled on statsmodels' results objects: the general solver's estimate, the systematic-error terms
(``evaluation.systematics``), the torque-gain scatter, the wrist-torque size, the tool-cable check and
the quality gate all read the same ``FittedModel`` instead of each rebuilding the regressor rows and
refitting them. It holds:

- the rows (``groups``, one per (sweep, joint)) of the sweeps the analysis uses, and each sweep's pose;
- the combined fit (``fit(ALL)``: θ, the row weights 1/σ², the normal inverse (YᵀWY)⁻¹, the
  autocorrelation-robust noise covariance) and ``cov_params()``, that covariance with the drive-gain
  uncertainty the model was built with (``wls.gain_covariance``);
- each pose's own fit (``fit(pose)``), made when first asked for (the quality gate and the systematic
  terms compare the poses; a plain solve never needs them);
- ``cached(key, make)``: anything else derived from the same fit once (the DH-length derivatives of
  the rows, the fits with nuisance offsets of ``evaluation.systematics.offsets``).

Every fit is made at most once per model; a fit that is impossible raises the same ``DataError`` (or
``LinAlgError``) each time it is asked for, so every consumer reports it as it did before.
``general.fit_model`` builds one from a run's deltas.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.types import SweepKey
from payload_agent.solvers.wls import FitResult, Group, fit, gain_covariance

ALL = "all"  # the combined fit's key (the others are pose names)


@dataclass(frozen=True, eq=False)
class FittedModel:
    """One analysis' weighted fit and what is derived from it (see the module docstring; compared by identity)."""

    deltas: Mapping[SweepKey, DeltaSweep]  # the data the model was made from (every sweep, raw and combined)
    kin: Kinematics
    sweeps: tuple[DeltaSweep, ...]  # the sweeps used (combined where both directions were recorded)
    groups: tuple[Group, ...]  # their rows, one group per (sweep, joint)
    pose_of: Mapping[str, str]  # sweep name -> pose
    gain_rel_std: tuple[float, ...] | None = None  # relative drive-gain uncertainty per joint (0-based)
    _cache: dict[Any, Any] = field(default_factory=dict, repr=False, compare=False)

    @property
    def poses(self) -> list[str]:
        return sorted(set(self.pose_of.values()))

    def groups_of(self, which: str = ALL) -> list[Group]:
        """The rows of the combined fit (``ALL``) or of one pose's own fit."""
        if which == ALL:
            return list(self.groups)
        return [g for g in self.groups if self.pose_of[g.sweep] == which]

    def fit(self, which: str = ALL) -> FitResult:
        """The weighted fit (noise covariance only) of ``groups_of(which)``, made once."""
        return self.cached(("fit", which), lambda: fit(self.groups_of(which)))

    def fits(self) -> dict[str, FitResult]:
        """The combined fit, then every pose that can be fitted alone (the others are left out)."""
        out = {}
        for which in (ALL, *self.poses):
            try:
                out[which] = self.fit(which)
            except (DataError, np.linalg.LinAlgError):
                continue
        return out

    @property
    def theta(self) -> np.ndarray:
        return self.fit(ALL).theta

    @property
    def weights(self) -> np.ndarray:
        return self.fit(ALL).weights

    @property
    def normal_inverse(self) -> np.ndarray:
        return self.fit(ALL).normal_inverse

    def cov_params(self) -> np.ndarray:
        """Covariance of the combined θ: the robust noise covariance plus the drive-gain term, if declared."""
        res = self.fit(ALL)
        if self.gain_rel_std is None:
            return res.cov
        return self.cached(("gain covariance",), lambda: res.cov + gain_covariance(
            list(self.groups), np.vstack([g.Y for g in self.groups]), res.weights, res.normal_inverse, res.theta,
            self.gain_rel_std))

    def cached(self, key: Any, make: Callable[[], Any]) -> Any:
        """``make()`` computed once per model under ``key`` (its exceptions are re-raised each time)."""
        if key not in self._cache:
            try:
                self._cache[key] = make()
            except (DataError, np.linalg.LinAlgError) as exc:
                self._cache[key] = exc
        got = self._cache[key]
        if isinstance(got, Exception):
            raise got
        return got


__all__ = ["ALL", "FittedModel"]
