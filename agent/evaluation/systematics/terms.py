"""A systematic error term and a run's set of them: what the recipe (``evaluation.systematics``) makes and what
the estimate and the quality gate add to their covariance."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from payload_agent.evaluation.systematics import compliance
from payload_agent.solvers.fitted import ALL
from payload_agent.solvers.results import Estimate


@dataclass(frozen=True)
class Term:
    """One systematic error source: P parameters' standard deviations and θ's response to each, and where the data
    estimate the error itself (a declared tool cable: ``cable_spring.term``), that estimate, removed from θ̂."""

    name: str
    std: np.ndarray  # (P,)
    sens: Mapping[str, np.ndarray]  # ALL or a pose -> (4, P) ∂θ/∂p (θ = [m, m·c] of that fit)
    note: str
    # ALL or a pose -> (4,) the error's estimate in θ of that fit, subtracted from the fit's θ̂ (σ then holds only
    # the estimate's own uncertainty); none: θ̂ as fitted
    shift: Mapping[str, np.ndarray] = field(default_factory=dict)
    # (P,) +1, or −1 for a parameter whose variance another part of σ already holds through a response this term
    # replaces (a declared cable's correction changes how the drive gains move θ̂: ``cable_spring.term``); none: all +1
    sign: np.ndarray | None = None

    @property
    def variances(self) -> np.ndarray:
        """(P,) each parameter's variance, signed (``sign``)."""
        return self.std ** 2 if self.sign is None else self.std ** 2 * self.sign

    def covariance(self, which: str = ALL) -> np.ndarray:
        A = self.sens.get(which)
        if A is None:
            return np.zeros((4, 4))
        return (A * self.variances) @ A.T


@dataclass
class Systematics:
    """Every term of a run; what the estimate and the quality gate add to their covariance."""

    terms: list[Term] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # terms that could not be evaluated, and why

    def covariance(self, which: str = ALL) -> np.ndarray:
        return sum((t.covariance(which) for t in self.terms), np.zeros((4, 4)))

    def shift(self, which: str = ALL) -> np.ndarray:
        """(4,) what the terms' estimates of their own errors take off θ̂ of fit ``which`` (``Term.shift``)."""
        return sum((np.asarray(t.shift[which], float) for t in self.terms if which in t.shift), np.zeros(4))

    def sensitivities(self, which: str) -> tuple[np.ndarray, np.ndarray]:
        """(A, v): all terms' ∂θ/∂p of one fit side by side (zeros where a term does not reach it) and the
        parameters' signed variances (``Term.variances``): the covariance is (A·v)·Aᵀ."""
        if not self.terms:
            return np.zeros((4, 0)), np.zeros(0)
        blocks = [t.sens.get(which, np.zeros((4, len(t.std)))) for t in self.terms]
        return np.hstack(blocks), np.concatenate([t.variances for t in self.terms])

    def apply(self, est: Estimate, which: str = ALL) -> Estimate:
        """``est`` with every term in its covariance and notes: a general fit on the prepared deltas (``which``
        ALL), or the three-step solver's on them (``THREE_STEP``: each term's three-step sensitivities)."""
        if est.covariance is None or not (self.terms or self.notes):
            return est
        cov = np.asarray(est.covariance, float).copy()
        cov[:4, :4] += self.covariance(which)
        out = compliance.with_covariance(shifted(est, self.shift(which)), cov)
        missing = [t.name for t in self.terms if which not in t.sens]
        lost = [f"the {' and '.join(missing)} term could not be propagated to {which} (not solvable on the shifted "
                "data); its σ leaves it out"] if missing else []
        return replace(out, notes=list(out.notes) + [t.note for t in self.terms if which in t.sens] + lost
                       + list(self.notes))

    def describe(self) -> str:
        return " + ".join(t.name for t in self.terms)


def shifted(est: Estimate, shift: np.ndarray) -> Estimate:
    """``est`` with ``shift`` (Δ[m, m·c]) taken off its mass and first moments; its covariance as it was."""
    if not np.any(shift):
        return est
    theta = np.array([est.mass_kg, *(est.mass_kg * np.asarray(est.cog_m))]) - shift
    return replace(est, mass_kg=float(theta[0]), cog_m=tuple(float(v) for v in theta[1:] / theta[0]))
