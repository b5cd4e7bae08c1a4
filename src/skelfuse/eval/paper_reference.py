"""The paper's own figures, as data, to print beside ours.

Source: Lee, S.-h.; Lee, D.-W.; Jun, K.; Lee, W.; Kim, M.S. "Markerless 3D Skeleton Tracking Algorithm by
Merging Multiple Inaccurate Skeleton Data from Multiple RGB-D Sensors", Sensors 2022, 22, 3155
(https://doi.org/10.3390/s22093155). Every number below is copied from the text of sections 3.1-3.3 (which
describe Figures 9-11); the figures themselves are bar charts without printed values.

What the numbers mean (checked against the Appendix tables):

- The error is the distance of each joint to the "ground truth", which in the paper is the skeleton of a fifth
  "best view" sensor placed in front of the subject (section 2.3), not an exact truth.
- The text calls the group figures "AE" (average error), but Figure 9's caption says "RMSE, STD" and the
  Appendix tables list RMSE and STD per joint and gesture. The group figure is the mean of the Appendix RMSEs
  over the group's joints and the six gestures: e.g. A1 upper limb = mean of the 24 Table A1/A2 RMSEs of
  L/R elbow and wrist = 91.0 mm, printed as 90.9 mm. So the paper's "AE" compares with our RMSE column, and
  its "STD" with the mean of the per-joint STDs (our STD column).
- Section 3.1 says A5's figure is the average over the DBSCAN radii 5, 10, 15, 20 cm; the Appendix shows
  A3 and A4 per radius too, so we take all three of section 3.1's figures as averages over the radii.
- Oddity: in Tables A1-A4 every A3 column (A3_5, A3_10, A3_15, A3_20) holds identical values for every joint
  and gesture, although A3 is DBSCAN with that radius; A4 and A5 do vary with the radius. Either A3 did not
  use the radius, or the same run was pasted four times. A3 is therefore absent from the paper's radius
  comparison (section 3.2 reports a single set of figures per radius, which match the A5 columns).
- Another oddity: the A1 torso STD is printed with two decimals (11.02, 44.89) where the others have one.
- Table A2's gesture-5 rows have 12 values for 13 columns, so a column is lost there; we use only the text.
"""

from __future__ import annotations

from typing import Any, Final

GROUPS: Final = ("torso", "upper_limb", "lower_limb")

CITATION: Final = "Lee et al. 2022, Sensors 22(9) 3155, https://doi.org/10.3390/s22093155"

# Section 3.1 / Figure 9: the algorithm ablation, 4 sensors, all gestures; A3-A5 averaged over eps 5-20 cm.
# A2 was left out by the paper ("no significant difference in performance with A1" on data without mirroring).
ALGORITHMS: Final[dict[str, dict[str, dict[str, float]]]] = {
    "A1": {
        "ae_mm": {"torso": 41.1, "upper_limb": 90.9, "lower_limb": 45.2},
        "std_mm": {"torso": 11.02, "upper_limb": 44.89, "lower_limb": 22.0},
    },
    "A3": {
        "ae_mm": {"torso": 40.8, "upper_limb": 66.0, "lower_limb": 38.9},
        "std_mm": {"torso": 13.1, "upper_limb": 40.1, "lower_limb": 17.8},
    },
    "A4": {
        "ae_mm": {"torso": 41.1, "upper_limb": 60.2, "lower_limb": 38.9},
        "std_mm": {"torso": 12.0, "upper_limb": 33.8, "lower_limb": 17.3},
    },
    "A5": {
        "ae_mm": {"torso": 39.9, "upper_limb": 55.9, "lower_limb": 36.2},
        "std_mm": {"torso": 10.3, "upper_limb": 29.3, "lower_limb": 14.2},
    },
}
ALGORITHMS_SECTION: Final = "section 3.1, Figure 9 (A3-A5: mean over eps 5/10/15/20 cm)"

# Section 3.2 / Figure 10: DBSCAN searching radius, A5 (the figures equal the A5_* columns of the Appendix).
EPS_SWEEP: Final[dict[float, dict[str, dict[str, float]]]] = {
    50.0: {
        "ae_mm": {"torso": 40.6, "upper_limb": 60.2, "lower_limb": 36.0},
        "std_mm": {"torso": 13.5, "upper_limb": 36.2, "lower_limb": 14.4},
    },
    100.0: {
        "ae_mm": {"torso": 39.1, "upper_limb": 51.6, "lower_limb": 35.7},
        "std_mm": {"torso": 9.6, "upper_limb": 26.7, "lower_limb": 13.8},
    },
    150.0: {
        "ae_mm": {"torso": 39.9, "upper_limb": 53.5, "lower_limb": 36.2},
        "std_mm": {"torso": 9.0, "upper_limb": 26.6, "lower_limb": 14.0},
    },
    200.0: {
        "ae_mm": {"torso": 39.9, "upper_limb": 58.1, "lower_limb": 36.8},
        "std_mm": {"torso": 9.0, "upper_limb": 27.8, "lower_limb": 14.4},
    },
}
EPS_SWEEP_PRESET: Final = "A5"
EPS_SWEEP_SECTION: Final = "section 3.2, Figure 10 (A5)"

# Section 3.3 / Figure 11: total number of sensors (TNOS), A5 at eps 10 cm; 1 sensor = raw data; averaged over
# all combinations of that size (4, 6, 4, 1).
N_SENSORS: Final[dict[int, dict[str, dict[str, float]]]] = {
    1: {
        "ae_mm": {"torso": 63.3, "upper_limb": 125.6, "lower_limb": 60.2},
        "std_mm": {"torso": 15.8, "upper_limb": 64.2, "lower_limb": 28.6},
    },
    2: {
        "ae_mm": {"torso": 50.9, "upper_limb": 103.5, "lower_limb": 46.8},
        "std_mm": {"torso": 13.6, "upper_limb": 57.5, "lower_limb": 20.3},
    },
    3: {
        "ae_mm": {"torso": 43.4, "upper_limb": 66.3, "lower_limb": 38.3},
        "std_mm": {"torso": 12.2, "upper_limb": 37.1, "lower_limb": 14.5},
    },
    4: {
        "ae_mm": {"torso": 39.6, "upper_limb": 51.8, "lower_limb": 35.8},
        "std_mm": {"torso": 9.8, "upper_limb": 26.0, "lower_limb": 13.2},
    },
}
N_SENSORS_COMBINATIONS: Final = {1: 4, 2: 6, 3: 4, 4: 1}
N_SENSORS_SECTION: Final = "section 3.3, Figure 11 (A5, eps 10 cm)"

ODDITIES: Final = (
    "Tables A1-A4: the A3 columns are identical for eps 5, 10, 15 and 20 cm, for every joint and gesture.",
    "The text's group 'AE' is the mean of the Appendix per-joint RMSEs (compare it with our RMSE).",
    "Section 3.1's A5 figure is the mean over eps 5-20 cm, not A5 at 10 cm (section 3.2 gives that).",
    "The paper's 'ground truth' is a best-view Kinect skeleton, which has errors of its own.",
)


def reference_value(experiment: str, key: str | int | float, metric: str, group: str) -> float | None:
    """The paper's figure for one bar, or None when the paper has none (e.g. A2, or A3 per eps).

    Parameters
    ----------
    experiment : "algorithms" | "eps_sweep" | "n_sensors"
    key : preset name ("A1".."A5"), eps in mm, or number of sensors
    metric : "ae_mm" | "std_mm"
    group : "torso" | "upper_limb" | "lower_limb"
    """
    tables: dict[str, dict[Any, Any]] = {"algorithms": ALGORITHMS, "eps_sweep": EPS_SWEEP, "n_sensors": N_SENSORS}
    table = tables.get(experiment, {})
    entry = table.get(key)
    if entry is None and isinstance(key, int | float) and not isinstance(key, bool):
        entry = table.get(float(key)) or table.get(int(key))
    if entry is None:
        return None
    return entry.get(metric, {}).get(group)
