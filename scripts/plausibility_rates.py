"""How often the plausibility stage holds a view out, per reason: false positives on clean and fast takes, and
what it catches in the simulated tracker-loss family.

Per world (the calibrated simulator profile, "baseline"; the same with only fast gestures; the ``tracker_loss``
failure family) and rig size: seeds x gestures (in turn), every view-frame where the view sees the person, the
share held out per reason (teleport, upside_down, bones) by the "skelfuse" preset on the single-person path.
For ``tracker_loss`` the simulator's own episode frames say which holds were right.

    PYTHONPATH=src python scripts/plausibility_rates.py [--seeds 1000 1001 ...] [--sensors 2 3 4] [--json]

``--json`` prints the counts with the run's stamp (docs/evidence.md, "Plausibility", renders them with
:func:`format_markdown`).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from skelfuse.cli.common import print_json
from skelfuse.cli.stamp import RunStamp
from skelfuse.fusion import Fuser, preset
from skelfuse.fusion.plausibility import HOLD_REASONS
from skelfuse.sim.failures import family_profile
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig

FPS = 30.0
DURATION_S = 10.0
WORLDS = {
    "clean": ("baseline", ("squat", "random", "hands_up_down", "walking", "jump", "lunge")),
    "fast gestures": ("baseline", ("jump", "random")),
    "tracker_loss": ("tracker_loss", ("squat", "random", "hands_up_down", "walking", "jump", "lunge")),
}


def held_counts(family: str, gesture: str, n_sensors: int, seed: int) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(reasons, seen view-frames) held per reason, and for tracker_loss: episode view-frames, caught ones."""
    rng = np.random.default_rng([seed, n_sensors])
    motion = make_gesture(gesture, duration_s=DURATION_S, fps=FPS, facing_deg=float(rng.uniform(0, 360)), seed=seed)
    base = load_profile()
    obs = simulate(motion, paper_rig(n_sensors), family_profile(base, family), seed=seed)
    world = np.where(obs.tracked[..., None, None], obs.positions_world(calibrated=True), np.nan)
    fuser = Fuser(preset("skelfuse"), 1, obs.world_from_sensor_calibrated[:, :3, 3])
    held = np.array(
        [fuser.step(world[t][None], obs.confidence[t][None], 1 / FPS).held_out[0] for t in range(len(world))]
    )
    counts = np.array([int(((held == k + 1) & obs.tracked).sum()) for k in range(len(HOLD_REASONS))])
    episodes = caught = 0
    if family == "tracker_loss":  # the frames the loss moved the view: where the clean take differs
        clean = simulate(motion, paper_rig(n_sensors), base, seed=seed).positions_world(calibrated=True)
        moved = np.linalg.norm(world[:, :, 0] - clean[:, :, 0], axis=-1) > 100.0  # pelvis moved (T, S)
        moved |= np.linalg.norm(world[:, :, 3] - clean[:, :, 3], axis=-1) > 100.0  # or the neck (upside down)
        moved &= obs.tracked
        episodes, caught = int(moved.sum()), int((moved & (held > 0)).sum())
    return counts, int(obs.tracked.sum()), episodes, caught


def measure(seeds: list[int], sensors: list[int]) -> dict[str, Any]:
    """Per world and rig size: view-frames seen, holds per reason, tracker-loss episode frames and caught ones."""
    rows = []
    for world, (family, gestures) in WORLDS.items():
        for n in sensors:
            total = np.zeros(len(HOLD_REASONS), dtype=np.int64)
            seen = episodes = caught = 0
            for k, seed in enumerate(seeds):
                c, s, e, h = held_counts(family, gestures[k % len(gestures)], n, seed)
                total += c
                seen, episodes, caught = seen + s, episodes + e, caught + h
            held = dict(zip(HOLD_REASONS, total.tolist(), strict=True))
            rows.append({"world": world, "sensors": n, "view_frames": seen, "held": held, "episode_frames": episodes,
                         "episode_frames_caught": caught})  # fmt: skip
    return {"seeds": seeds, "duration_s": DURATION_S, "worlds": {w: list(g) for w, (_, g) in WORLDS.items()},
            "rows": rows}  # fmt: skip


def format_markdown(result: dict[str, Any]) -> str:
    """The share of seen view-frames held per reason, and the tracker-loss episode frames caught."""
    seeds = result["seeds"]
    worlds = "; ".join(w + ": " + ", ".join(g) for w, g in result["worlds"].items())
    lines = [
        f"Seeds {', '.join(map(str, seeds))}, {result['duration_s']:g} s takes, gestures in turn "
        f"({worlds}), random facing; share of "
        "the view-frames in which a view saw the person.",
        "",
        "| world | sensors | view-frames | "
        + " | ".join(f"{r} %" for r in HOLD_REASONS)
        + " | episode frames caught |",
        "|---|---|---|" + "---|" * len(HOLD_REASONS) + "---|",
    ]
    for row in result["rows"]:
        seen, episodes = row["view_frames"], row["episode_frames"]
        shares = " | ".join(f"{100 * row['held'][r] / max(seen, 1):.3f}" for r in HOLD_REASONS)
        caught = row["episode_frames_caught"]
        catch = f"{caught} / {episodes} ({100 * caught / episodes:.0f} %)" if episodes else "-"
        lines.append(f"| {row['world']} | {row['sensors']} | {seen} | {shares} | {catch} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(1000, 1006)))
    parser.add_argument("--sensors", type=int, nargs="+", default=[2, 3, 4])
    parser.add_argument("--json", action="store_true", help="print the counts as JSON, stamped")
    args = parser.parse_args()
    args.stamp = (
        RunStamp.begin(sys.argv[1:], program=("python", "scripts/plausibility_rates.py")) if args.json else None
    )
    result = measure(args.seeds, args.sensors)
    if args.json:
        print_json(result, args)
    else:
        print(format_markdown(result))


if __name__ == "__main__":
    main()
