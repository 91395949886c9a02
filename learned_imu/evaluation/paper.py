"""Numbers quoted from the AirIMU paper (Qiu et al.), shown beside ours as labelled reference columns.

Nothing here is computed: these are the paper's published values for the EuRoC test sequences that the shared
data holds (MH_04_difficult, V1_03_difficult, V2_02_medium), keyed by sequence, then setting, then our metric
field (``learned_imu.evaluation.metrics`` says which field is which column of the paper's tables). Units are ours:
degrees and
metres (the paper's 10-frame P-RMSE is printed in cm there and stored here in m). "Brossard et al." are the
paper's quoted values for Brossard et al.'s gyro denoising network (ROE and RMSE only).

``TUMVI_IMU`` holds its TUM-VI table (rooms 2, 4, 6). ``KITTI_IMU`` holds its KITTI table (drives 0014, 0018,
0029 of 2011_09_26). The deterministic EuRoC Baseline rows
(raw IMU) check our metric definitions: ``tests/learned_imu/evaluation/test_paper_metrics.py`` reproduces them within
3 %.
"""

from __future__ import annotations

# field -> value, per setting, per sequence
EUROC_IMU: dict[str, dict[str, dict[str, float]]] = {
    "MH_04_difficult": {
        "Baseline": {
            "roe_deg": 4.5391,
            "roe_rmse_deg": 4.5406,
            "rpe_rmse_m": 0.1904,
            "roe_rmse_10f_deg": 0.229,
            "rpe_rmse_10f_m": 0.00326,
        },
        "Brossard et al.": {"roe_deg": 0.1067, "roe_rmse_deg": 0.3556},
        "AirIMU": {
            "roe_deg": 0.0708,
            "roe_rmse_deg": 0.0836,
            "rpe_rmse_m": 0.0415,
            "roe_rmse_10f_deg": 0.025,
            "rpe_rmse_10f_m": 0.00325,
        },
    },
    "V1_03_difficult": {
        "Baseline": {
            "roe_deg": 4.4870,
            "roe_rmse_deg": 4.4909,
            "rpe_rmse_m": 0.2116,
            "roe_rmse_10f_deg": 0.231,
            "rpe_rmse_10f_m": 0.00048,
        },
        "Brossard et al.": {"roe_deg": 0.1935, "roe_rmse_deg": 0.2181},
        "AirIMU": {
            "roe_deg": 0.1884,
            "roe_rmse_deg": 0.2107,
            "rpe_rmse_m": 0.0583,
            "roe_rmse_10f_deg": 0.036,
            "rpe_rmse_10f_m": 0.00042,
        },
    },
    "V2_02_medium": {
        "Baseline": {
            "roe_deg": 4.6924,
            "roe_rmse_deg": 4.7000,
            "rpe_rmse_m": 0.1520,
            "roe_rmse_10f_deg": 0.240,
            "rpe_rmse_10f_m": 0.00028,
        },
        "Brossard et al.": {"roe_deg": 0.2389, "roe_rmse_deg": 0.2595},
        "AirIMU": {
            "roe_deg": 0.2157,
            "roe_rmse_deg": 0.2366,
            "rpe_rmse_m": 0.0851,
            "roe_rmse_10f_deg": 0.037,
            "rpe_rmse_10f_m": 0.00027,
        },
    },
}

# The KITTI table (ROE 1 s, deg; RPE 1 s, m: mean window-end errors) on the test drives of the shared data. The
# paper's KITTI stream is the 10 Hz ``sync`` data; ours the 100 Hz OXTS extract (README of kitti_raw), so the raw-IMU
# rows differ by construction.
KITTI_IMU: dict[str, dict[str, dict[str, float]]] = {
    "2011_09_26_drive_0014": {
        "Baseline": {"roe_deg": 0.4137, "rpe_m": 0.1785},
        "AirIMU": {"roe_deg": 0.3927, "rpe_m": 0.1699},
    },
    "2011_09_26_drive_0018": {
        "Baseline": {"roe_deg": 0.2451, "rpe_m": 0.0715},
        "AirIMU": {"roe_deg": 0.2388, "rpe_m": 0.0857},
    },
    "2011_09_26_drive_0029": {
        "Baseline": {"roe_deg": 0.3435, "rpe_m": 0.393},
        "AirIMU": {"roe_deg": 0.3245, "rpe_m": 0.3562},
    },
}

# its TUM-VI table (rooms 2, 4, 6 of the 512_16 exports; ROE deg, RPE m over 1 s). Its "Baseline" matches the rooms'
# raw IMU and its "Kalibr + Baseline" TUM-VI's calibrated IMU (README's TUM-VI section measures both)
TUMVI_IMU: dict[str, dict[str, dict[str, float]]] = {
    "dataset-room2_512_16": {
        "Baseline": {"roe_deg": 2.3161, "rpe_m": 0.7652},
        "Kalibr + Baseline": {"roe_deg": 0.7006, "rpe_m": 0.0785},
        "AirIMU": {"roe_deg": 0.6765, "rpe_m": 0.0770},
    },
    "dataset-room4_512_16": {
        "Baseline": {"roe_deg": 2.8239, "rpe_m": 0.7558},
        "Kalibr + Baseline": {"roe_deg": 0.4397, "rpe_m": 0.0571},
        "AirIMU": {"roe_deg": 0.3930, "rpe_m": 0.0540},
    },
    "dataset-room6_512_16": {
        "Baseline": {"roe_deg": 2.3407, "rpe_m": 0.8521},
        "Kalibr + Baseline": {"roe_deg": 0.3923, "rpe_m": 0.4096},
        "AirIMU": {"roe_deg": 0.3743, "rpe_m": 0.4093},
    },
}
# the paper's means over the three rooms, as it prints them
TUMVI_MEAN = {"Baseline": {"roe_deg": 2.4936, "rpe_m": 0.7910}, "AirIMU": {"roe_deg": 0.4813, "rpe_m": 0.1801}}

# PGO ablation (ATE, m), per sequence, GPS rate (Hz), setting (ours: airimu.experiments.pgo.SETTINGS; the
# paper's "VINS" fixed covariance is our "fixed cov")
EUROC_PGO: dict[str, dict[float, dict[str, float]]] = {
    "MH_04_difficult": {
        1.0: {
            "raw IMU + fixed cov": 0.1491,
            "AirIMU + fixed cov": 0.1486,
            "raw IMU + learned cov": 0.1327,
            "AirIMU + learned cov": 0.1024,
        },
        0.1: {
            "raw IMU + fixed cov": 3.6112,
            "AirIMU + fixed cov": 0.2955,
            "raw IMU + learned cov": 4.3450,
            "AirIMU + learned cov": 0.2754,
        },
    },
    "V1_03_difficult": {
        1.0: {
            "raw IMU + fixed cov": 0.1549,
            "AirIMU + fixed cov": 0.1547,
            "raw IMU + learned cov": 0.1310,
            "AirIMU + learned cov": 0.1039,
        },
        0.1: {
            "raw IMU + fixed cov": 1.4474,
            "AirIMU + fixed cov": 0.3085,
            "raw IMU + learned cov": 1.4248,
            "AirIMU + learned cov": 0.2905,
        },
    },
    "V2_02_medium": {
        1.0: {
            "raw IMU + fixed cov": 0.1542,
            "AirIMU + fixed cov": 0.1540,
            "raw IMU + learned cov": 0.1569,
            "AirIMU + learned cov": 0.1060,
        },
        0.1: {
            "raw IMU + fixed cov": 1.6840,
            "AirIMU + fixed cov": 0.8681,
            "raw IMU + learned cov": 2.1213,
            "AirIMU + learned cov": 0.8927,
        },
    },
}


def reference(table: dict, sequence: str, setting: str, field: str) -> float | None:
    """The paper's value, or None where the paper has none (another sequence, setting or metric)."""
    return table.get(sequence, {}).get(setting, {}).get(field)
