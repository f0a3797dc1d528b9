"""Drive gains from the controller's own target signals, for a run with no stored calibration.

A UR streams, with every sample, the current it commands (``target_current``) and the torque
its model asks for (``target_moment``); the recorder keeps both as the sweep CSVs'
``target_current1..6`` / ``target_moment1..6`` columns. Their per-joint fit
(``torque_constants.fit_torque_constants``, one run per phase: offsets and friction may differ
between the empty and the loaded run) gives the controller's own current-to-torque constant.
``run_gains`` uses it, when no calibration is stored, for every joint it determines; the
others keep the config's nominal gain, and ``gains_source`` says which joints came from where.

Each joint's relative uncertainty is its fit's σ combined with ``CONTROLLER_CONSTANT_REL_STD``
(how far the controller's constant may be from the drive's, as for ``payload-agent import``).
Before any run (``plan --target-std`` on a fresh state) there is nothing to fit; a driver that declares it
records the signals (``Driver.records_controller_targets``, read from its class without connecting) gets
``declared_gains``: the nominal gains with the declared σ, which is what the run will carry (the fit's own
part is a few 0.01 %).
"""

from __future__ import annotations

import csv
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from payload_agent.evaluation.recorded_motion import CONTROLLER_CONSTANT_REL_STD
from payload_agent.evaluation.torque_constants import SOURCE, TorqueConstants, fit_torque_constants
from payload_agent.recording.rundata import N_JOINTS, PHASES, Q_COLUMNS, TIME_COLUMNS, load_manifest

TARGET_CURRENT_COLUMNS = tuple(f"target_current{j}" for j in range(1, N_JOINTS + 1))
TARGET_MOMENT_COLUMNS = tuple(f"target_moment{j}" for j in range(1, N_JOINTS + 1))
MIN_ROWS = 20  # a sweep with fewer complete rows adds nothing to the fit
# Speeds below this count as standstill: the derivative of a recorded (noisy) angle at rest flips sign from
# sample to sample, and the fit's Coulomb term sign(q̇) would then switch a friction feed-forward the
# controller does not command at rest (a real UR's fades out near zero speed).
STANDSTILL_RAD_S = 0.02


@dataclass(frozen=True)
class ControllerGains:
    """The gains a run is analysed with when they come (partly) from the controller's signals."""

    nm_per_a: tuple[float, ...]
    rel_std: tuple[float, ...]  # 0 for a joint left at its nominal gain (its error is not known)
    source: str
    constants: TorqueConstants | None  # None: not fitted yet (``declared_gains``)


def read_target_signals(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(t s, q rad, target current A, target moment N·m) of one sweep CSV; None when it has no target
    columns or too few complete rows (a recording of another driver, or a torn file)."""
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            header = [h.strip() for h in (next(csv.reader(fh), None) or [])]
    except OSError:
        return None
    wanted = (*Q_COLUMNS, *TARGET_CURRENT_COLUMNS, *TARGET_MOMENT_COLUMNS)
    times = [c for c in TIME_COLUMNS if c in header]
    if not times or any(c not in header for c in wanted):
        return None
    cols = [header.index(c) for c in (*times, *wanted)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, ndmin=2, usecols=cols,
                            invalid_raise=False)
    nt = len(times)
    if raw.size == 0:
        return None
    data = raw[:, nt:]
    t = next((raw[:, k] for k in range(nt) if np.isfinite(raw[:, k]).all()), None)
    if t is None:
        return None
    keep = np.isfinite(data).all(axis=1)
    keep[1:] &= np.diff(t) > 0  # repeated or backward times would break the speeds
    if int(keep.sum()) < MIN_ROWS:
        return None
    t, data = t[keep], data[keep]
    return t, data[:, :N_JOINTS], data[:, N_JOINTS:2 * N_JOINTS], data[:, 2 * N_JOINTS:]


def joint_speeds(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """q̇ (rad/s) from recorded angles and times, zero below ``STANDSTILL_RAD_S``."""
    qd = np.gradient(q, t, axis=0)
    qd[np.abs(qd) < STANDSTILL_RAD_S] = 0.0
    return qd


def run_constants(run_dir: Path, manifest: Mapping[str, Any] | None = None) -> TorqueConstants | None:
    """The constants fitted from every complete sweep's target signals, or None when none has them."""
    run_dir = Path(run_dir)
    manifest = manifest or load_manifest(run_dir)
    runs = []
    for phase in PHASES:
        parts = []
        for entry in ((manifest.get("phases") or {}).get(phase) or {}).get("sweeps", []):
            if entry.get("status") != "complete" or "file" not in entry:
                continue
            sig = read_target_signals(run_dir / str(entry["file"]))
            if sig is not None:
                t, q, i_target, tau_target = sig
                parts.append((i_target, tau_target, joint_speeds(t, q)))
        if parts:
            runs.append(tuple(np.concatenate([p[k] for p in parts]) for k in range(3)))
    return fit_torque_constants(runs) if runs else None


def records_controller_targets(driver_type: str) -> bool:
    """Whether the driver named ``driver_type`` records the controller's target current and moment (its class
    attribute, through the driver registry: nothing is connected)."""
    from payload_agent.drivers.registry import driver_class

    return bool(getattr(driver_class(driver_type), "records_controller_targets", False))


def declared_gains(nominal_nm_per_a) -> ControllerGains:
    """What a run that will fit the controller's constants is known to carry before it: the nominal gains, each
    joint's uncertainty the declared ``CONTROLLER_CONSTANT_REL_STD`` (no fit yet: ``constants`` is None)."""
    gains = tuple(float(g) for g in nominal_nm_per_a)
    return ControllerGains(gains, (CONTROLLER_CONSTANT_REL_STD,) * len(gains),
                           f"{SOURCE}, to be fitted by the run (declared uncertainty "
                           f"{100 * CONTROLLER_CONSTANT_REL_STD:g} %)", None)


def controller_gains(nominal_nm_per_a, run_dir: Path) -> ControllerGains | None:
    """Nominal gains with every joint the controller's signals determine replaced by its fitted constant;
    None when the run has no target signals or they determine no joint."""
    constants = run_constants(run_dir)
    if constants is None or not any(constants.determined):
        return None
    gains = [float(g) for g in nominal_nm_per_a]
    rel = [0.0] * len(gains)
    for j, (k, s, ok) in enumerate(zip(constants.k_nm_per_a, constants.std_nm_per_a, constants.determined)):
        if ok:
            gains[j], rel[j] = float(k), float(np.hypot(s / k, CONTROLLER_CONSTANT_REL_STD))
    fitted = [str(j + 1) for j, ok in enumerate(constants.determined) if ok]
    others = [str(j + 1) for j, ok in enumerate(constants.determined) if not ok]
    source = f"{SOURCE}, joints {', '.join(fitted)}"
    if others:
        source += f"; nominal effort.gains_nm_per_unit for joints {', '.join(others)}"
    return ControllerGains(tuple(gains), tuple(rel), source, constants)
