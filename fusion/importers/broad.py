"""Importer of one BROAD trial: IMU + magnetometer under magnetic disturbance, optical reference.

BROAD (Laidig, Caruso, Cereatti, Seel, *Data* 6(7):72, 2021, CC BY 4.0): a myon aktos-t IMU
on a hand-held board, 285.714 Hz, with OptiTrack orientation and position synchronized and
aligned to the IMU (``datasets/broad/README.md``). One ``.mat`` file per trial; the output
recording:

``imu.csv``
    The board's own axes are right-handed with z up (at rest ``f ≈ (0.1, 0.0, 9.86) m/s²``);
    the board has no direction of travel, so b = the IMU axes unchanged (x → x right,
    y → y forward, z → z up). Time ``t = k / fs`` from the file's ``sampling_rate``.

``magnetometer.csv``
    ``imu_mag`` (µT, IMU axes, calibrated by the dataset authors), every
    ``magnetometer_decimation``-th sample (default 10 → 28.6 Hz; a point sample, not averaged,
    so a disturbance is not smeared). ``meta.yaml`` gives the expected earth field of the
    laboratory *in the optical reference frame*, a site constant measured once in the rest
    phases of the two undisturbed trials (05 and 21: field rotated into the optical ENU frame
    by the optical attitude): declination 0.5° (the optical frame's y axis is magnetic north
    within that), inclination 69.0°, 43.8 µT. The same figures serve every trial.

``position.csv``
    The optical position, decimated to ``position_rate_hz`` (default 10 Hz: the sample nearest
    each 0.1 s step, skipping occluded ones) with a declared σ of ``position_sigma_m``
    (default 5 mm: the OptiTrack position is mm-level, and the optical point sits about 1 cm
    from the IMU — a least-squares lever-arm fit on trial 21 gives ≈ (−8, 1, −5) mm — which the
    importer neglects, lever arm 0). No synthetic noise is added to the real data.

``truth.csv``
    Optical position and attitude (``opt_quat`` [w, x, y, z] of the IMU w.r.t. ENU →
    ``C_b^n`` → roll, pitch, yaw in the format's convention) at every sample where *both* are
    finite; velocity by central differences of the optical position over ±5 samples (35 ms),
    never across a gap. **Gaps in the optical reference** (occluded markers: NaN quaternion or
    position; 2.5–9 % of the samples, the first second always) are absent rows, as the format
    prescribes — never interpolated here. Each gap ``[t_last_before, t_first_after]`` is listed
    in ``extra.truth_gaps`` and counted in the report; a scorer must not bridge them (the
    benchmark compares the solution at the truth rows only). The ``cycle`` column marks BROAD's
    scored movement phase: 1 inside ``movement``, 0 in the rest phases.

    The recording starts at the first sample with a finite optical attitude and position (the
    first second of every trial is occluded), so that the initial state is the reference's.

``meta.yaml``
    Origin: a nominal geodetic point for the Berlin laboratory (TU Berlin, 52.512° N,
    13.327° E, 50 m; only gravity and earth rate depend on it). Initial state: optical position
    and attitude at the first sample, velocity 0 (rest phase); σ 5 mm, 0.01 m/s, 0.5°/0.5°/1°.
    ``imu.spec``: no datasheet figures for the aktos-t are at hand, so the figures are a
    characterization from the rest phases of the undisturbed trials 05 and 21 (the same
    constants for every trial): white noise 0.36 °/√h and 0.42 mg/√Hz (largest axis of
    ``std · √Δt``); turn-on gyro bias up to 800 °/h across the 11 trials → a prior of
    1000 °/h; accelerometer bias prior 5 mg (the rest |f| differs from normal gravity by
    0.5–2.3 mg).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fusion.attitude import euler_from_quat
from fusion.importers.common import (
    ImportReport,
    central_difference_velocity,
    load_mat,
    make_meta,
    true_runs,
    write_validated,
)
from fusion.recording import (
    FORMAT,
    ImuData,
    MagnetometerData,
    PositionData,
    Recording,
    TruthData,
)

VARIABLES = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos", "movement", "sampling_rate")
LAB_ORIGIN = {"lat_deg": 52.512, "lon_deg": 13.327, "height_m": 50.0}
"""Nominal geodetic point of the laboratory (TU Berlin)."""
SITE_FIELD = {"declination_deg": 0.5, "inclination_deg": 69.0, "field_uT": 43.8}
"""Earth field in the optical ENU frame, from the rest phases of undisturbed trials 05 and 21."""
IMU_SPEC = {
    "gyro_bias_deg_h": 1000.0,
    "gyro_arw_deg_rth": 0.36,
    "accel_bias_mg": 5.0,
    "accel_vrw_mg_rthz": 0.42,
}
VELOCITY_HALF_WINDOW = 5
"""Samples each side of the central difference giving the reference velocity."""


def import_broad(
    src: str | Path,
    out: str | Path,
    *,
    magnetometer_decimation: int = 10,
    position_rate_hz: float = 10.0,
    position_sigma_m: float = 0.005,
) -> ImportReport:
    """Convert one BROAD trial (``.mat``) into a recording directory.

    Parameters
    ----------
    src : str or Path
        The trial's ``.mat`` file.
    out : str or Path
        Recording directory to write.
    magnetometer_decimation : int, default 10
        Keep every n-th magnetometer sample.
    position_rate_hz : float, default 10
        Rate of the optical position fixes.
    position_sigma_m : float, default 0.005
        Declared 1-σ of each fix (m).

    Returns
    -------
    ImportReport

    Raises
    ------
    DatasetError
        The file is unreadable or lacks a BROAD variable.
    """
    if magnetometer_decimation < 1:
        raise ValueError(f"magnetometer_decimation must be >= 1 (got {magnetometer_decimation})")
    if position_rate_hz <= 0 or position_sigma_m <= 0:
        raise ValueError("position_rate_hz and position_sigma_m must be > 0")
    src = Path(src)
    report = ImportReport("broad", src, Path(out))
    data = load_mat(src, VARIABLES)
    fs = float(np.ravel(data["sampling_rate"])[0])
    quat = np.asarray(data["opt_quat"], dtype=float)
    pos = np.asarray(data["opt_pos"], dtype=float)
    movement = np.ravel(data["movement"]).astype(bool)
    n = quat.shape[0]
    t_all = np.arange(n) / fs

    has_att = np.isfinite(quat).all(axis=1)
    has_pos = np.isfinite(pos).all(axis=1)
    reference = has_att & has_pos
    # First sample that starts a run of at least two reference samples (it then has a velocity).
    first = int(np.argmax(reference[:-1] & reference[1:]))
    sl = slice(first, n)
    report.notes.append(
        f"recording starts at sample {first} (t = {t_all[first]:.3f} s), the first with a "
        "finite optical attitude and position; the occluded samples before it are dropped"
    )
    report.notes.append("IMU axes (right-handed, z up at rest) taken as b unchanged")
    t = t_all[sl]

    velocity, has_vel = central_difference_velocity(t, pos[sl], VELOCITY_HALF_WINDOW, reference[sl])
    rows = reference[sl] & has_vel
    # rows[0] is True by construction; a trailing gap ends at the last IMU sample.
    gaps = [
        [round(float(t[a - 1]), 6), round(float(t[min(b, t.size - 1)]), 6)]
        for a, b in true_runs(~rows)
    ]
    report.notes.append(
        f"optical reference gaps: {int(np.sum(~has_att[sl]))} samples without attitude, "
        f"{int(np.sum(~has_pos[sl]))} without position, {int(np.sum(~rows))} truth rows "
        f"absent in {len(gaps)} gap(s) (longest {_longest(gaps):.3f} s; listed in "
        "extra.truth_gaps); nothing interpolated"
    )
    attitude = euler_from_quat(quat[sl][rows])

    fix_grid = np.arange(t[0], t[-1], 1.0 / position_rate_hz)
    fix_idx = np.unique(np.clip(np.round((fix_grid - t[0]) * fs).astype(int), 0, t.size - 1))
    fix_idx = fix_idx[has_pos[sl][fix_idx]]
    report.notes.append(
        f"position.csv: optical position at {position_rate_hz:g} Hz ({fix_idx.size} fixes, "
        f"occluded ones skipped), declared sigma {position_sigma_m * 1000:g} mm, lever arm 0"
    )
    mag_idx = np.arange(0, t.size, magnetometer_decimation)
    report.notes.append(
        f"magnetometer.csv: every {magnetometer_decimation}th sample "
        f"({fs / magnetometer_decimation:.2f} Hz); expected field = site constant {SITE_FIELD}"
    )
    report.notes.append("truth.csv cycle = 1 in BROAD's movement phase, 0 in the rest phases")

    meta = make_meta(
        {
            "format": FORMAT,
            "name": f"BROAD {src.stem}",
            "origin": LAB_ORIGIN,
            "initial": {
                "position_enu_m": pos[first].tolist(),
                "velocity_enu_mps": [0.0, 0.0, 0.0],
                "attitude_deg": dict(
                    zip(
                        ("roll", "pitch", "yaw"),
                        np.degrees(attitude[0]).tolist(),
                        strict=True,
                    )
                ),
                "sigma": {
                    "position_m": [0.005, 0.005, 0.005],
                    "velocity_mps": [0.01, 0.01, 0.01],
                    "attitude_deg": [0.5, 0.5, 1.0],
                },
            },
            "imu": {"rate_hz": fs, "spec": IMU_SPEC},
            "magnetometer": {"rate_hz": fs / magnetometer_decimation, **SITE_FIELD},
            "position": {"lever_arm_b_m": [0.0, 0.0, 0.0]},
            "extra": {
                "importer": "broad",
                "source": "dlaidig/broad data_mat (CC BY 4.0; Laidig et al., Data 6(7):72, "
                "2021, doi:10.3390/data6070072)",
                "trial": src.stem,
                "imu_spec_source": "characterized from the rest phases of undisturbed trials "
                "05 and 21 (no aktos-t datasheet at hand)",
                "site_field_source": "rest phases of undisturbed trials 05 and 21, field "
                "rotated into the optical ENU frame",
                "truth_gaps": gaps,
                "truth_cycle": "1 = BROAD movement phase (scored), 0 = rest phases",
                "import_notes": report.notes,
            },
        },
        f"{src} (broad importer)",
    )
    gyro = np.asarray(data["imu_gyr"], dtype=float)[sl]
    accel = np.asarray(data["imu_acc"], dtype=float)[sl]
    mag = np.asarray(data["imu_mag"], dtype=float)[sl]
    recording = Recording(
        path=None,
        meta=meta,
        imu=ImuData(t=t, gyro=gyro, accel=accel),
        magnetometer=MagnetometerData(t=t[mag_idx], field=mag[mag_idx]),
        position=PositionData(
            t=t[fix_idx],
            enu=pos[sl][fix_idx],
            sigma=np.full((fix_idx.size, 3), position_sigma_m),
        ),
        truth=TruthData(
            t=t[rows],
            position=pos[sl][rows],
            velocity=velocity[rows],
            attitude=attitude,
            cycle=movement[sl][rows].astype(np.int64),
        ),
    )
    return write_validated(recording, report)


def _longest(gaps: list[list[float]]) -> float:
    return max((b - a for a, b in gaps), default=0.0)
