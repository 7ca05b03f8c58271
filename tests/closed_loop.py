"""Closed-loop flight logs for the tests: a roll-rate airframe flown with PX4's rate law in the loop, written as
a ULog with the topics and parameters PX4 logs (independent of tuner: scipy for the plant, the law written here
from ../shared/reference/firmware.md).

The plant as logged: normalised torque setpoint -> the body rate PX4 publishes (vehicle_angular_velocity, after the
gyro's second-order low-pass at 40 Hz): ``250/(s (0.02 s + 1))`` times the low-pass. The torque is held for a sample
(the mixer and the ESCs hold it); turbulence is a torque added at the plant's input (low-passed white noise); the
gyro's noise enters the measurement the law reads (and the log records). 400 Hz.

* ``hover``: the rate setpoint is 0; only the turbulence drives the loop;
* ``sweep``: the rate setpoint sweeps (an exponential chirp, as PX4's system-identification mode), turbulence and
  gyro noise on top.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import signal

DT = 0.0025
W_GYRO = 2 * math.pi * 40.0
NUM = [250.0 * W_GYRO**2]
DEN = list(np.polymul([0.02, 1.0, 0.0], [1.0, math.sqrt(2) * W_GYRO, W_GYRO**2]))
GAINS = {"P": 0.15, "I": 0.2, "D": 0.003, "FF": 0.0, "K": 1.0, "dgyro_hz": 20.0, "int_lim": 0.3}
PARAMS = {"MC_ROLLRATE_P": 0.15, "MC_ROLLRATE_I": 0.2, "MC_ROLLRATE_D": 0.003, "MC_ROLLRATE_FF": 0.0,
          "MC_ROLLRATE_K": 1.0, "MC_RR_INT_LIM": 0.3, "IMU_DGYRO_CUTOFF": 20.0, "IMU_GYRO_CUTOFF": 40.0,
          "IMU_GYRO_RATEMAX": 400}


@dataclass
class Log:
    t: np.ndarray
    r: np.ndarray  # rate setpoint, rad/s
    u: np.ndarray  # torque setpoint (the law's output)
    y: np.ndarray  # the logged rate (the law's measurement)


def true_zoh_response(w: np.ndarray) -> np.ndarray:
    """The plant as logged, held at DT: ``u[k] -> y[k]`` exactly (scipy's ZOH)."""
    b, a, _ = signal.cont2discrete((NUM, DEN), DT, method="zoh")
    _, h = signal.freqz(np.ravel(b), a, worN=np.asarray(w) * DT)
    return h


def law_response(w: np.ndarray) -> np.ndarray:
    """PX4's feedback path C(e^{jw DT}) with GAINS, written from firmware.md (forward-Euler I, D on the filtered
    derivative of the measurement)."""
    z = np.exp(1j * np.asarray(w) * DT)
    a = DT / (DT + 1 / (2 * math.pi * GAINS["dgyro_hz"]))
    d = a * z / (z - (1 - a)) * (z - 1) / (DT * z)
    return GAINS["K"] * (GAINS["P"] + GAINS["I"] * DT / (z - 1) + GAINS["D"] * d)


def fly(kind: str, *, seconds: float = 60.0, seed: int = 0, turbulence: float = 0.05, gyro_noise: float = 0.01,
        sweep_amplitude: float = 1.0) -> Log:
    """A flight of ``kind`` ``"hover"`` or ``"sweep"``."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds / DT))
    t = np.arange(n) * DT
    A, B, C, _ = signal.tf2ss(NUM, DEN)
    Ad, Bd, _, _, _ = signal.cont2discrete((A, B, C, np.zeros((1, 1))), DT, method="zoh")
    Bd = Bd.ravel()
    bt, at = signal.butter(1, 2 * 5.0 * DT)  # turbulence: white noise low-passed at 5 Hz
    turb = turbulence * signal.lfilter(bt, at, rng.standard_normal(n)) / math.sqrt(bt[0])
    noise = gyro_noise * rng.standard_normal(n)
    if kind == "hover":
        r = np.zeros(n)
    elif kind == "sweep":
        w0, w1 = 1.0, 150.0
        ph = w0 * seconds / math.log(w1 / w0) * (np.exp(t / seconds * math.log(w1 / w0)) - 1.0)
        r = sweep_amplitude * np.sin(ph)
    else:
        raise ValueError(kind)
    g = GAINS
    a = DT / (DT + 1 / (2 * math.pi * g["dgyro_hz"]))
    x = np.zeros(A.shape[0])
    xi = y_prev = yd = 0.0
    u = np.zeros(n)
    y = np.zeros(n)
    for k in range(n):
        y[k] = float((C @ x)[0]) + noise[k]
        e = r[k] - y[k]
        yd += a * ((y[k] - y_prev) / DT - yd)
        y_prev = y[k]
        u[k] = g["K"] * (g["P"] * e - g["D"] * yd) + xi + g["FF"] * r[k]
        xi = min(max(xi + g["K"] * g["I"] * e * DT, -g["int_lim"]), g["int_lim"])
        x = Ad @ x + Bd * (u[k] + turb[k])  # held over the sample
    return Log(t=t, r=r, u=u, y=y)


def write(log: Log, path: Path, extra: tuple = ()) -> Path:
    """The flight as a PX4 ULog: vehicle_torque_setpoint.xyz, vehicle_angular_velocity.xyz (with its
    timestamp_sample), vehicle_rates_setpoint.roll, and the rate controller's parameters; ``extra``: more topics
    (ulog_writer Topics: the vehicle's state)."""
    from ulog_writer import Topic, write_ulog

    ts = (1_000_000 + np.round(log.t * 1e6)).astype(np.int64)
    n = ts.size
    zeros = np.zeros(n)
    tq = Topic("vehicle_torque_setpoint", [("float", "xyz", 3)], ts, {"xyz": np.stack([log.u, zeros, zeros], 1)})
    av = Topic("vehicle_angular_velocity", [("uint64_t", "timestamp_sample", 0), ("float", "xyz", 3)], ts,
               {"timestamp_sample": ts, "xyz": np.stack([log.y, zeros, zeros], 1)})
    sp = Topic("vehicle_rates_setpoint", [("float", "roll", 0), ("float", "pitch", 0), ("float", "yaw", 0)], ts,
               {"roll": log.r, "pitch": zeros, "yaw": zeros})
    return write_ulog(path, [tq, av, sp, *extra], params=PARAMS)
