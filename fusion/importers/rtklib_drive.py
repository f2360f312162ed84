"""Importer of ``rtklib-drive``: a car with a roof-mounted MEMS IMU (100 Hz) and RTK GNSS (4 Hz).

Source files (``datasets/rtklib-drive/``, see its README): ``imu_gpst.csv`` (the IMU log in SI
units with each line's arrival time on the GPS clock, ``t_arrival``) and ``gnss_rtk.csv`` (the
RTKLIB solution, GPS seconds of week). The output recording:

``imu.csv``
    Sensor axes x backward, y right, z up (checked by the dataset's maintainer against the
    GNSS course and the along-track acceleration) mapped to the recording's body frame
    (x right, y forward, z up) by the proper rotation ::

        v_b = (v_y, −v_x, v_z)_sensor,      det = +1,

    applied to the angular rate and the specific force alike. The board is *not* rotated into
    the car: b is the IMU board, pitched about 7° nose-down relative to the car (at rest
    ``f_y ≈ −1.2 m/s²``), with a few degrees of residual yaw. That misalignment is left in the
    data on purpose: the motion-constraint plugin estimates it (its ``mounting_angles``); the
    author's own estimate is recorded under ``extra.author_imu_misalignment_deg`` for comparison.

    Time base: the IMU clock is not the GPS clock. ``t = t_arrival − imu_lag_s`` with a default
    lag of 0.120 s, the dataset maintainer's cross-correlation of the IMU yaw rate with the GNSS
    course rate (0.105 s on the first half, 0.125 s on the second, ±0.02 s; symmetric
    differences in ``tests/test_importers.py`` find 0.110 s). The lag is an option so that a
    benchmark can show what it is worth; it is recorded in ``extra``.

    Vibration: the samples are raw and unfiltered (the chip's own anti-alias filter only), so
    engine vibration is in the data: 1 σ of 2.3/0.6/0.1 °/s and 0.09/0.07/0.14 m/s² on the b
    x/y/z axes over the initial standstill, 5.4/1.8/0.4 °/s and 0.4–0.5 m/s² (above 4 Hz) while
    driving — two orders of magnitude above the datasheet noise. The importer does not filter
    it (a low-pass filter would change the signal the format defines as the mean over each
    interval); it measures it over the initial standstill and records it under
    ``extra.standstill_vibration``, and ``imu.spec`` keeps the datasheet figures. A
    configuration for this recording must therefore inflate the IMU noise explicitly.

``position.csv``
    Every RTK epoch (2189 fixed, 8 float) as a fix of the antenna with the solution's own σ
    (``sde, sdn, sdu``). Lever arm: the author's configuration puts the antenna 5 cm to the
    left of the IMU (FRD offsets [0, −0.05, −0.65] and [0, 0, −0.65] m), i.e. ``[−0.05, 0, 0]``
    in b.

``truth.csv``
    The same RTK track (the only reference: RTK-fixed, about 1–3 cm), velocity from the
    solution's N/E/U velocity. The dataset has **no attitude reference**: the attitude columns
    hold the *course attitude* of the car (yaw = course over ground, pitch = flight-path angle,
    roll = 0; held through standstills), which differs from the board's attitude by the mounting
    misalignment. ``extra.truth_attitude`` says so; score position and velocity only.

``meta.yaml``
    Origin at the first RTK position; time origin GPS second of week 243258.0 (week 2374).
    Initial state at the first IMU sample: RTK position and velocity interpolated there; roll and
    pitch by levelling the mean specific force over the initial standstill (σ 1°: a 10 mg
    accelerometer bias tilts it by 0.6°); yaw = the GNSS course when the car first exceeds
    1 m/s (the car does not turn while parked), σ 10° to cover the board-to-car yaw
    misalignment and the turn during drive-off. ``imu.spec``: the noise densities from the
    author's configuration ``src/drive_config.py`` of ``rtklibexplorer/GNSS_IMU`` (which names
    the IMU a TDK ICM-45686 and the receiver a u-blox X20): gyro 0.0038 °/s/√Hz = 0.228 °/√h,
    accelerometer 70 µg/√Hz; bias priors from the same file's initial uncertainties
    (0.1 °/s = 360 °/h, 0.1 m/s² = 10.2 mg).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fusion.earth import LocalFrame
from fusion.importers.common import (
    DatasetError,
    ImportReport,
    course_attitude,
    leveling_angles,
    make_meta,
    read_csv_columns,
    write_validated,
)
from fusion.recording import FORMAT, ImuData, PositionData, Recording, TruthData

IMU_FILE = "imu_gpst.csv"
GNSS_FILE = "gnss_rtk.csv"
GNSS_COLUMNS: tuple[str, ...] = ("t", "lat_deg", "lon_deg", "h_m", "Q", "sdn_m", "sde_m")
GNSS_COLUMNS += ("sdu_m", "vn_mps", "ve_mps", "vu_mps")
DEFAULT_IMU_LAG_S = 0.120
"""Sampling lag of the IMU log behind its arrival time (dataset README, cross-correlation)."""
TIME_ORIGIN_GPS_SOW = 243258.0
"""GPS second of week (week 2374) taken as t = 0 of the recording."""
STANDSTILL_SPEED_MPS = 0.1
"""RTK horizontal speed below which the car is parked."""
COURSE_SPEED_MPS = 1.0
"""Horizontal speed above which the course over ground defines the heading."""
ANTENNA_LEVER_ARM_B_M = (-0.05, 0.0, 0.0)
"""Antenna relative to the IMU in b (author's configuration: 5 cm to the left)."""
AUTHOR_MISALIGNMENT_DEG = {"roll": -0.29, "pitch": -6.60, "yaw": 5.35}
"""IMU-to-body residual misalignment (rpy, FRD body) in the author's drive_config.py."""
IMU_SPEC = {
    "gyro_bias_deg_h": 360.0,
    "gyro_arw_deg_rth": 0.0038 * 60.0,
    "accel_bias_mg": 10.2,
    "accel_vrw_mg_rthz": 0.070,
}

# Sensor (x backward, y right, z up) -> b (x right, y forward, z up): v_b = M v_sensor.
SENSOR_TO_BODY = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def import_rtklib_drive(
    src: str | Path, out: str | Path, *, imu_lag_s: float = DEFAULT_IMU_LAG_S
) -> ImportReport:
    """Convert the ``rtklib-drive`` folder into a recording directory.

    Parameters
    ----------
    src : str or Path
        The dataset folder holding ``imu_gpst.csv`` and ``gnss_rtk.csv``.
    out : str or Path
        Recording directory to write.
    imu_lag_s : float, default 0.120
        Sampling lag subtracted from each IMU line's arrival time (0 keeps the arrival time).

    Returns
    -------
    ImportReport
        The explicit handling of the dataset's quirks (also in ``meta.yaml`` ``extra``).

    Raises
    ------
    DatasetError
        A source file is missing or lacks a column, or the data has no standstill/drive-off.
    """
    src = Path(src)
    report = ImportReport("rtklib-drive", src, Path(out))
    imu = read_csv_columns(src / IMU_FILE, ("t_arrival", "fx", "fy", "fz", "wx", "wy", "wz"))
    gnss = read_csv_columns(
        src / GNSS_FILE,
        GNSS_COLUMNS,
    )

    t_imu = imu["t_arrival"] - imu_lag_s - TIME_ORIGIN_GPS_SOW
    gyro = np.column_stack([imu["wx"], imu["wy"], imu["wz"]]) @ SENSOR_TO_BODY.T
    accel = np.column_stack([imu["fx"], imu["fy"], imu["fz"]]) @ SENSOR_TO_BODY.T
    report.notes.append(
        "IMU axes x backward, y right, z up mapped to b = (y, -x, z)_sensor (x right, "
        "y forward, z up); the ~7 deg board pitch and few-degree yaw relative to the car are "
        "kept (b is the board), to be estimated by the motion constraint"
    )
    report.notes.append(
        f"IMU time = arrival time - {imu_lag_s:.3f} s sampling lag"
        + (" (dataset README estimate, +-0.02 s)" if imu_lag_s == DEFAULT_IMU_LAG_S else "")
    )

    t_gnss = gnss["t"] - TIME_ORIGIN_GPS_SOW
    frame = LocalFrame(float(gnss["lat_deg"][0]), float(gnss["lon_deg"][0]), float(gnss["h_m"][0]))
    enu = frame.to_enu(np.deg2rad(gnss["lat_deg"]), np.deg2rad(gnss["lon_deg"]), gnss["h_m"])
    vel = np.column_stack([gnss["ve_mps"], gnss["vn_mps"], gnss["vu_mps"]])
    sigma = np.column_stack([gnss["sde_m"], gnss["sdn_m"], gnss["sdu_m"]])
    n_float = int(np.sum(gnss["Q"] != 1))
    report.notes.append(
        f"position.csv: all {t_gnss.size} RTK epochs ({n_float} not fixed, Q!=1) with the "
        "solution's own sigma; antenna lever arm [-0.05, 0, 0] m in b"
    )

    speed = np.hypot(vel[:, 0], vel[:, 1])
    moving = np.flatnonzero(speed > STANDSTILL_SPEED_MPS)
    if moving.size == 0 or t_gnss[moving[0]] - 1.0 <= t_imu[0]:
        raise DatasetError(f"{src}: no standstill at the start of the IMU log to level on")
    static = t_imu < t_gnss[moving[0]] - 1.0
    roll, pitch = leveling_angles(accel[static].mean(axis=0))
    drive_off = np.flatnonzero(speed >= COURSE_SPEED_MPS)[:2]
    yaw = float(np.mod(np.arctan2(vel[drive_off, 0], vel[drive_off, 1]).mean(), 2 * np.pi))
    position0 = [float(np.interp(t_imu[0], t_gnss, enu[:, k])) for k in range(3)]
    velocity0 = [float(np.interp(t_imu[0], t_gnss, vel[:, k])) for k in range(3)]
    vibration = {
        "gyro_deg_s": np.degrees(gyro[static].std(axis=0)).round(4).tolist(),
        "accel_mps2": accel[static].std(axis=0).round(4).tolist(),
        "axes": "b (x right, y forward, z up), 1 sigma over the initial standstill",
        "seconds": round(float(t_imu[static][-1] - t_imu[0]), 2),
    }
    report.notes.append(
        "raw unfiltered IMU kept; standstill vibration (1 sigma, b axes) gyro "
        f"{vibration['gyro_deg_s']} deg/s, accel {vibration['accel_mps2']} m/s^2 "
        "(datasheet noise is ~100x lower: inflate the IMU noise in the configuration)"
    )
    report.notes.append(
        "truth.csv attitude is the car's course attitude (yaw = course, pitch = flight-path "
        "angle, roll = 0), not an attitude reference: the dataset has none"
    )

    meta = make_meta(
        {
            "format": FORMAT,
            "name": "rtklib-drive 2025-07-08 19:34 GPST (car, ICM-45686 + u-blox X20 RTK)",
            "origin": {
                "lat_deg": float(gnss["lat_deg"][0]),
                "lon_deg": float(gnss["lon_deg"][0]),
                "height_m": float(gnss["h_m"][0]),
            },
            "initial": {
                "position_enu_m": position0,
                "velocity_enu_mps": velocity0,
                "attitude_deg": {
                    "roll": float(np.degrees(roll)),
                    "pitch": float(np.degrees(pitch)),
                    "yaw": float(np.degrees(yaw)),
                },
                "sigma": {
                    "position_m": [0.02, 0.02, 0.03],
                    "velocity_mps": [0.05, 0.05, 0.05],
                    "attitude_deg": [1.0, 1.0, 10.0],
                },
            },
            "imu": {"rate_hz": 100.0, "spec": IMU_SPEC},
            "position": {"lever_arm_b_m": list(ANTENNA_LEVER_ARM_B_M)},
            "extra": {
                "importer": "rtklib-drive",
                "source": "rtklibexplorer/GNSS_IMU data/drive_0708 (BSD-3-Clause, "
                "Copyright (c) 2025, rtklibexplorer)",
                "time_origin": {"gps_week": 2374, "gps_sow": TIME_ORIGIN_GPS_SOW},
                "imu_lag_s": imu_lag_s,
                "imu_spec_source": "rtklibexplorer/GNSS_IMU src/drive_config.py noise PSDs "
                "and initial bias uncertainties (IMU named there: TDK ICM-45686)",
                "author_imu_misalignment_deg": AUTHOR_MISALIGNMENT_DEG,
                "standstill_vibration": vibration,
                "truth_attitude": "course attitude of the car (yaw = course over ground, "
                "pitch = flight-path angle, roll = 0, held at standstill); NOT an attitude "
                "reference and not the IMU board's attitude",
                "import_notes": report.notes,
            },
        },
        f"{src} (rtklib-drive importer)",
    )
    recording = Recording(
        path=None,
        meta=meta,
        imu=ImuData(t=t_imu, gyro=gyro, accel=accel),
        position=PositionData(t=t_gnss, enu=enu, sigma=sigma),
        truth=TruthData(
            t=t_gnss,
            position=enu,
            velocity=vel,
            attitude=course_attitude(vel, COURSE_SPEED_MPS),
            cycle=np.zeros(t_gnss.size, dtype=np.int64),
        ),
    )
    return write_validated(recording, report)
