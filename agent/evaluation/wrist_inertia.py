"""The inertia part of a run: the tensor about the centre of mass from the wrist moves, checked and made consistent.

Pure: it takes the wrist moves of both phases (``recording.rundata.load_wrist_moves``), the
kinematics and the static result's m, m·c and their covariance, and returns what a user reads:

1. the fit (``solvers.inertia_fit``): six inertia parameters on loaded − empty, m and m·c updated from the
   static result where the wrist moves agree with it, else held;
2. the tensor about the centre of mass with the 6×6 covariance of its elements (delta method);
3. when the estimate is not physically possible, its projection onto the consistent set in the
   covariance metric (``solvers.inertia_consistency``), and the result says so;
4. the quality check (``inertia_support``): the inertia is refused (mass and CoM still given) when any
   element's σ exceeds ``INERTIA_MAX_REL_STD`` of the largest principal moment: a light, compact tool
   whose inertial torques drown in the noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from payload_agent.errors import DataError
from payload_agent.evaluation.inertia_support import uncertainty_problem
from payload_agent.model.kinematics import Kinematics
from payload_agent.recording.rundata import WristRecord
from payload_agent.solvers.inertia_consistency import project_consistent, to_tensor
from payload_agent.solvers.inertia_fit import fit_inertia


@dataclass(frozen=True)
class InertiaResult:
    estimate_kgm2: np.ndarray  # (3, 3) about the CoM, flange axes: consistent (projected where needed)
    std_kgm2: np.ndarray  # (3, 3) σ of each element (of the unprojected estimate: the projection adds no information)
    refused: str | None  # why the data cannot support it, or None
    inconsistent_data: str | None  # what the data alone gave, when they were not physically possible
    moves: tuple[str, ...]
    condition_number: float
    samples: int
    static_held: str | None = None  # why m, m·c were held at the sweeps' result (None: updated by the wrist moves)
    static_nis: float = float("nan")  # the wrist moves' m, m·c against the sweeps' (normalised innovation squared)

    @property
    def inertia_com_kgm2(self) -> np.ndarray | None:
        return None if self.refused else self.estimate_kgm2

    @property
    def inertia_com_std_kgm2(self) -> np.ndarray | None:
        return None if self.refused else self.std_kgm2

    def notes(self) -> list[str]:
        out = []
        if self.inconsistent_data:
            out.append(f"inertia: the wrist moves alone gave a tensor that is {self.inconsistent_data}; the one given "
                       "is the nearest physically possible tensor (in the estimate's covariance metric)")
        if self.static_held and self.samples:
            out.append(f"inertia: {self.static_held}")
        if self.refused:
            out.append(f"inertia not given: {self.refused}")
        return out

    def to_json(self) -> dict:
        known = not np.isnan(self.estimate_kgm2).any()
        return {
            "inertia_com_kgm2": None if self.refused else self.estimate_kgm2.tolist(),
            "inertia_com_std_kgm2": None if self.refused else self.std_kgm2.tolist(),
            "inertia": {"refused": self.refused, "consistent_from_data": self.inconsistent_data is None,
                        "inconsistency": self.inconsistent_data,
                        "estimate_kgm2": self.estimate_kgm2.tolist() if known else None,
                        "std_kgm2": self.std_kgm2.tolist() if known else None, "wrist_moves": list(self.moves),
                        "condition_number": self.condition_number, "samples": self.samples,
                        "first_moments": "held at the sweeps' result" if self.static_held else
                        "updated by the wrist moves, the sweeps' result as prior",
                        "first_moments_nis": None if np.isnan(self.static_nis) else self.static_nis,
                        "method": "wrist moves, m and m·c from the sweeps (docs/analysis.md, Inertia)"},
        }


def support_problem(inertia: np.ndarray, std: np.ndarray) -> str | None:
    """Why the data do not support this (consistent) tensor, or None (``inertia_support``)."""
    return uncertainty_problem(inertia, std)


def identify_inertia(loaded: Mapping[str, WristRecord], empty: Mapping[str, WristRecord], kin: Kinematics,
                     theta_static: np.ndarray, cov_static: np.ndarray, *,
                     gain_rel_std: list[float] | None = None) -> InertiaResult:
    """The inertia part's result; DataError when no wrist move is in both phases."""
    fit = fit_inertia(loaded, empty, kin, theta_static, cov_static, gain_rel_std=gain_rel_std)
    raw, cov6 = fit.inertia_com()
    std = to_tensor(np.sqrt(np.maximum(np.diag(cov6), 0.0)))
    tensor, problem = project_consistent(raw, cov6)
    return InertiaResult(tensor, std, support_problem(tensor, std), problem, fit.moves, fit.condition_number,
                         fit.samples, fit.static_held, fit.static_nis)


def identify_or_none(loaded: Mapping[str, WristRecord], empty: Mapping[str, WristRecord], kin: Kinematics,
                     theta_static: np.ndarray, cov_static: np.ndarray, **kw) -> InertiaResult | None:
    """None for a run without wrist moves (older runs, the inertia part off); a refusal when they cannot be used."""
    if not loaded and not empty:
        return None
    try:
        return identify_inertia(loaded, empty, kin, theta_static, cov_static, **kw)
    except DataError as exc:
        nan = np.full((3, 3), np.nan)
        return InertiaResult(nan, nan, f"the wrist moves could not be analysed: {exc}", None, (), float("nan"), 0)
