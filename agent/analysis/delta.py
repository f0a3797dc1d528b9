"""Baseline subtraction: loaded minus empty effort at the same joint angles.

Sweeps are matched by pose, joint, direction and speed; the empty run's effort is
interpolated at the loaded run's angles of the moving joint, within the overlap of
both constant-speed windows. What remains is the payload's gravity torque (plus
whatever friction did not cancel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from payload_agent.errors import DataError
from payload_agent.types import SweepKey
from payload_agent.recording.rundata import SweepData
from payload_agent.analysis.segmenter import Window, constant_speed_window


@dataclass
class DeltaSweep:
    key: SweepKey
    q: np.ndarray  # (n, 6) loaded-run angles, rad
    dtau: np.ndarray  # (n, 6) loaded - empty effort, N·m
    speed_rad_s: float

    @property
    def moving(self) -> int:
        return self.key.joint - 1


def window_of(sweep: SweepData) -> Window:
    j = sweep.key.joint - 1
    return constant_speed_window(sweep.t, sweep.q[:, j], where=sweep.source)


def subtract(loaded: SweepData, empty: SweepData) -> DeltaSweep:
    if loaded.key != empty.key:
        raise DataError(f"cannot subtract {empty.key} from {loaded.key}: different sweeps")
    j = loaded.key.joint - 1
    wl, we = window_of(loaded), window_of(empty)
    xe = empty.q[we.slice, j]
    ye = empty.effort_nm[we.slice]
    order = np.argsort(xe)
    xe, ye = xe[order], ye[order]
    q = loaded.q[wl.slice]
    x = q[:, j]
    inside = (x >= xe[0]) & (x <= xe[-1])
    if inside.sum() < 20:
        raise DataError(f"{loaded.source}: the loaded and empty sweeps hardly overlap in joint {j + 1} angle "
                        f"({inside.sum()} samples); was the baseline recorded with the same procedure?")
    q = q[inside]
    x = x[inside]
    empty_at = np.column_stack([np.interp(x, xe, ye[:, c]) for c in range(ye.shape[1])])
    return DeltaSweep(loaded.key, q, loaded.effort_nm[wl.slice][inside] - empty_at, wl.speed_rad_s)


def subtract_all(loaded: dict[SweepKey, SweepData], empty: dict[SweepKey, SweepData]) -> dict[SweepKey, DeltaSweep]:
    missing = [k.name for k in loaded if k not in empty]
    if missing:
        raise DataError(f"the empty-flange baseline has no sweep matching {', '.join(missing)} "
                        f"(same pose, joint, direction and speed)")
    return {k: subtract(v, empty[k]) for k, v in loaded.items()}
