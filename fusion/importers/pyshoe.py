"""Importer of one PyShoe VICON trial: foot-mounted IMU (200 Hz) with Vicon position truth.

PyShoe (Wagstaff, Peretroukhin, Kelly, IEEE Sensors J. 20(2), 2019; data doi:10.21227/v1z6-9z84):
a LORD MicroStrain 3DM-GX3-25 on the foot, processed ``.mat`` files with the IMU, the Vicon
position at every IMU time step and per-detector "optimal" zero-velocity flags
(``datasets/pyshoe-vicon/README.md``). The output recording:

``imu.csv``
    The sensor frame is x forward (toward the toes), y right, z **down**: at rest with the
    foot flat the specific force is ``(−2.7, 0.4, −9.4) m/s²`` — z down, and x sloping about
    16° down toward the toes along the instep. Mapped to b (x right, y forward, z up) by the
    proper rotation (180° about the forward axis, then the axis relabelling) ::

        v_b = (v_y, v_x, −v_z)_sensor,     det = +1.

    "x forward" was checked, not assumed: a strapdown integration with velocity resets at the
    zero-velocity flags moves along +y_b stride after stride (stride direction minus the
    y_b heading within ±40° on the eight walking/running trials, never near 180°). Time: the
    file's ``ts`` (s, irregular 4.0–6.2 ms steps around 5 ms).

    Not every trial has the foot flat at rest: the 2018 trials were recorded with other
    mountings or motions (stairs, crawling); in ``2018-02-22-10-08-52`` the mapped ``f_z`` at
    rest is −8.9 m/s² (sensor upside down relative to a flat foot). The importer does not
    "fix" that: the initial roll and pitch come from levelling, whatever they are, and the
    report says when the mapped specific force at rest does not point up.

``truth.csv``
    Vicon position (``gt``, m, z up: the foot rises in the swing) at the IMU time steps, with
    its y axis **mirrored** (``(x, −y, z)``): as given, the Vicon axes form a *left-handed*
    frame. Evidence: the IMU triad is right-handed (with the gyro negated, a zero-velocity
    strapdown gets stride lengths wrong by metres instead of 2–4 cm on the walking trials), yet
    its heading turns against the Vicon course (the mechanized yaw decreases by 360° per lap
    while the course increases). PyShoe's own pipeline does not see it because it compares its
    INS output in a left-handed (N, E, up) frame. Velocity by central differences over ±5
    samples (25 ms). **No attitude reference**: the attitude columns are zero
    placeholders (``extra.truth_attitude``). The Vicon frame is *not* heading-aligned with the
    navigation frame (PyShoe aligns trajectories before scoring), so position errors are
    meaningful only after a yaw-and-translation alignment (``benchmarks/real.py``).

``meta.yaml``
    Origin: a nominal geodetic point for the University of Toronto (43.66° N, −79.40° E,
    100 m). Initial state at the first sample: Vicon position, velocity 0; roll and pitch by
    levelling the mean specific force over the first zero-velocity run of the trial's best
    detector (at most 0.5 s), σ 1°; yaw = the direction of the first 0.8 m of horizontal Vicon
    displacement (of the farthest point when the foot never gets 0.8 m away, said in the
    report), since the foot points roughly along the walking direction, σ 30°: the foot heading
    in the Vicon frame is not measured. ``imu.spec``: 3DM-GX3-25 datasheet figures as
    recalled (gyro noise density 0.03 °/s/√Hz = 1.8 °/√h, turn-on bias ±0.25 °/s = 900 °/h;
    accelerometer 80 µg/√Hz, bias 5 mg) — not checked against the document here, see
    ``extra.imu_spec_source``.

The zero-velocity labels and the PyShoe errors (``trial_error``, ``best_error``) are not part
of the recording format; a scorer reads them from the ``.mat`` file
(:func:`read_pyshoe_labels`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.importers.common import (
    DatasetError,
    ImportReport,
    central_difference_velocity,
    leveling_angles,
    load_mat,
    make_meta,
    true_runs,
    write_validated,
)
from fusion.recording import FORMAT, ImuData, Recording, TruthData

VARIABLES = ("ts", "imu", "gt", "best_detector", "best_error", "trial_error")
DETECTORS = ("shoe", "ared", "amvd", "mbgtd", "vicon")
"""Order of ``trial_error`` in the files."""
LAB_ORIGIN = {"lat_deg": 43.66, "lon_deg": -79.40, "height_m": 100.0}
"""Nominal geodetic point of the laboratory (University of Toronto)."""
IMU_SPEC = {
    "gyro_bias_deg_h": 900.0,
    "gyro_arw_deg_rth": 1.8,
    "accel_bias_mg": 5.0,
    "accel_vrw_mg_rthz": 0.08,
}
ALIGN_DISTANCE_M = 0.8
"""Horizontal displacement whose direction sets the initial yaw (PyShoe's alignment distance)."""
LEVEL_MAX_S = 0.5
VELOCITY_HALF_WINDOW = 5

VICON_MIRROR = np.array([1.0, -1.0, 1.0])
"""Turns the left-handed Vicon axes of the processed files into a right-handed frame."""

# Sensor (x forward, y right, z down) -> b (x right, y forward, z up): v_b = M v_sensor.
SENSOR_TO_BODY = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class PyShoeLabels:
    """What a PyShoe trial says beyond the sensor data.

    Attributes
    ----------
    t : ndarray, shape (N,)
        IMU times (s), the recording's clock.
    zero_velocity : ndarray of bool, shape (N,)
        The "optimal" zero-velocity flags of the trial's best detector.
    best_detector : str
        Which detector produced them (``shoe``, ``ared``, ``amvd``, ``mbgtd``, ``vicon``).
    best_error : float
        PyShoe's 2-D ARMSE of its INS with those flags (m).
    trial_error : dict of str to float
        The same error for each detector at its optimal threshold (m).
    """

    t: NDArray[np.float64]
    zero_velocity: NDArray[np.bool_]
    best_detector: str
    best_error: float
    trial_error: dict[str, float]


def read_pyshoe_labels(src: str | Path) -> PyShoeLabels:
    """Read the zero-velocity labels and PyShoe's own errors of a trial.

    Raises
    ------
    DatasetError
        The file lacks a variable (including ``zv_<best_detector>_opt``).
    """
    data = load_mat(src, VARIABLES)
    best = str(np.ravel(data["best_detector"])[0]).strip()
    key = f"zv_{best}_opt"
    if key not in data:
        raise DatasetError(f"{src}: missing variable {key} (best_detector is {best!r})")
    errors = np.ravel(data["trial_error"]).astype(float)
    return PyShoeLabels(
        t=np.ravel(data["ts"]).astype(float),
        zero_velocity=np.ravel(data[key]).astype(bool),
        best_detector=best,
        best_error=float(np.ravel(data["best_error"])[0]),
        trial_error=dict(zip(DETECTORS, errors.tolist(), strict=True)),
    )


def import_pyshoe(src: str | Path, out: str | Path) -> ImportReport:
    """Convert one PyShoe VICON trial (``.mat``) into a recording directory.

    Parameters
    ----------
    src : str or Path
        The trial's ``.mat`` file.
    out : str or Path
        Recording directory to write.

    Returns
    -------
    ImportReport

    Raises
    ------
    DatasetError
        The file is unreadable or lacks a variable.
    """
    src = Path(src)
    report = ImportReport("pyshoe", src, Path(out))
    data = load_mat(src, VARIABLES)
    labels = read_pyshoe_labels(src)
    t = labels.t
    raw = np.asarray(data["imu"], dtype=float)
    accel = raw[:, 0:3] @ SENSOR_TO_BODY.T
    gyro = raw[:, 3:6] @ SENSOR_TO_BODY.T
    gt = np.asarray(data["gt"], dtype=float) * VICON_MIRROR
    report.notes.append(
        "IMU axes x forward, y right, z down mapped to b = (y, x, -z)_sensor (x right, "
        "y forward, z up)"
    )

    first_rest = true_runs(labels.zero_velocity)
    if first_rest and first_rest[0][0] == 0:
        stop = min(first_rest[0][1], int(np.searchsorted(t, t[0] + LEVEL_MAX_S)))
    else:
        stop = int(np.searchsorted(t, t[0] + 0.1))
        report.notes.append("trial does not start at rest: levelled over the first 0.1 s")
    f0 = accel[: max(stop, 2)].mean(axis=0)
    roll, pitch = leveling_angles(f0)
    if f0[2] < 0.5 * np.linalg.norm(f0):
        report.notes.append(
            f"at rest the mapped specific force is {np.round(f0, 2).tolist()} m/s^2, not "
            "+g on z: the sensor is not on a flat foot in this trial; initial roll/pitch "
            f"from levelling = {np.degrees(roll):.1f}/{np.degrees(pitch):.1f} deg"
        )

    travel = np.hypot(gt[:, 0] - gt[0, 0], gt[:, 1] - gt[0, 1])
    far = np.flatnonzero(travel >= ALIGN_DISTANCE_M)
    if far.size:
        k = int(far[0])
        how = f"the first {ALIGN_DISTANCE_M} m of Vicon travel"
    else:
        k = int(np.argmax(travel))
        how = (
            f"the farthest Vicon point ({travel[k]:.2f} m: the track never moves "
            f"{ALIGN_DISTANCE_M} m from its start)"
        )
    d = gt[k, :2] - gt[0, :2]
    yaw = float(np.mod(np.arctan2(d[0], d[1]), 2.0 * np.pi))
    report.notes.append(
        f"initial yaw {np.degrees(yaw):.1f} deg = direction of {how} (sigma 30 deg); "
        "score after yaw alignment"
    )
    velocity, has_vel = central_difference_velocity(t, gt, VELOCITY_HALF_WINDOW)
    if not has_vel.all():
        raise DatasetError(f"{src}: the Vicon track has non-finite samples")
    report.notes.append(
        "truth.csv: Vicon position with y mirrored (the file's Vicon axes are left-handed), "
        "frame not heading-aligned, velocity by central differences; attitude columns are "
        "zero placeholders (no attitude reference)"
    )
    report.notes.append(
        f"zero-velocity labels (zv_{labels.best_detector}_opt) and best_error "
        f"{labels.best_error} m stay in the .mat file (read_pyshoe_labels)"
    )

    meta = make_meta(
        {
            "format": FORMAT,
            "name": f"PyShoe VICON {src.stem}",
            "origin": LAB_ORIGIN,
            "initial": {
                "position_enu_m": gt[0].tolist(),
                "velocity_enu_mps": [0.0, 0.0, 0.0],
                "attitude_deg": {
                    "roll": float(np.degrees(roll)),
                    "pitch": float(np.degrees(pitch)),
                    "yaw": float(np.degrees(yaw)),
                },
                "sigma": {
                    "position_m": [0.005, 0.005, 0.005],
                    "velocity_mps": [0.01, 0.01, 0.01],
                    "attitude_deg": [1.0, 1.0, 30.0],
                },
            },
            "imu": {"rate_hz": round(float(1.0 / np.median(np.diff(t))), 1), "spec": IMU_SPEC},
            "extra": {
                "importer": "pyshoe",
                "source": "University of Toronto foot-mounted inertial navigation dataset, "
                "VICON processed files (Wagstaff et al.; doi:10.21227/v1z6-9z84)",
                "trial": src.stem,
                "imu_spec_source": "LORD MicroStrain 3DM-GX3-25 datasheet figures as "
                "recalled, not verified against the document",
                "truth_attitude": "none: the attitude columns are zero placeholders",
                "truth_frame": "Vicon frame with y mirrored (x, -y, z) to make it right-handed; "
                "not heading-aligned with the navigation frame",
                "best_detector": labels.best_detector,
                "best_error_m": labels.best_error,
                "import_notes": report.notes,
            },
        },
        f"{src} (pyshoe importer)",
    )
    recording = Recording(
        path=None,
        meta=meta,
        imu=ImuData(t=t, gyro=gyro, accel=accel),
        truth=TruthData(
            t=t,
            position=gt,
            velocity=velocity,
            attitude=np.zeros((t.size, 3)),
            cycle=np.zeros(t.size, dtype=np.int64),
        ),
    )
    return write_validated(recording, report)
