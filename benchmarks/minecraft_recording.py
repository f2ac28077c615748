"""Record every episode type on the real-Minecraft backend once and check what each recording holds.

    .venv/bin/python benchmarks/minecraft_recording.py                     # all 17 types, ~12 min on 2 cores
    .venv/bin/python benchmarks/minecraft_recording.py --types walkLook rotationEval --resolution 64

Needs ``solaris-engine setup-minecraft``. One bot pair at a time (a fresh server per episode). Writes
``benchmarks/results/minecraft_recording.json`` with one row per type:

* ``ticks``, ``wall_s`` (server restart, logins, chunk warm-up and encoding included) and
  ``real_time_factor`` = ticks / 20 / wall_s;
* per bot: ``frames`` (decoded from the mp4), ``records`` (the action JSON) and ``frames_equal_records``;
  event counts over the records (``place_block``, ``mine`` ticks, ``attack``, ``sneak`` ticks, hotbar presses);
* ``blocks`` / ``hits``: ground-truth edit and hit counts; ``summary``: the choreographies' own report
  (built / placed / mined / reached ...); ``catchup_ticks``, ``look_resets``, ``aborted``;
* eval types: ``eval_metadata`` and the judge's ``queries`` (``eval_protocol.query_frames``: bots, frames,
  expected answer, frame1) and the ``eval_ids`` row, exactly as for the voxel engine's recordings.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).parent / "results" / "minecraft_recording.json"


def _frame_count(path: Path) -> int:
    import cv2

    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n


def record_type(session, out: Path, episode_type: str, episode: int, size: int) -> dict:
    from solaris_env.engine import eval_protocol as ep
    from solaris_env.engine.recorder import EpisodeKey

    is_eval = episode_type in ep.EVAL_KEYS
    key = EpisodeKey(episode, 0, eval_type=episode_type) if is_eval else EpisodeKey(episode, 0, batch=0)
    t0 = time.perf_counter()
    res = session.record(out, key, episode_type, 0, size, size, split="test" if is_eval else "train")
    wall = time.perf_counter() - t0
    d = out / ("eval" if is_eval else "duet") / (episode_type if is_eval else "train")
    d = d / "test" if is_eval else d
    gt = json.loads((d / key.sidecar_name).read_text())
    records, bots = {}, {}
    for bot in key.players:
        stem = key.bot_stem(bot)
        records[bot] = json.loads((d / f"{stem}.json").read_text())
        frames = _frame_count(d / (f"{stem}_camera.mp4" if is_eval else f"{stem}.mp4"))
        acts = [r["action"] for r in records[bot]]
        bots[bot] = {"frames": frames, "records": len(acts), "frames_equal_records": frames == len(acts),
                     "place_block": sum(a["place_block"] for a in acts), "mine_ticks": sum(a["mine"] for a in acts),
                     "attack": sum(a["attack"] for a in acts), "sneak_ticks": sum(a["sneak"] for a in acts),
                     "hotbar_presses": sum(any(a[f"hotbar.{k}"] for k in range(1, 10)) for a in acts)}
    row = {"type": episode_type, "ticks": res["ticks"], "wall_s": round(wall, 1),
           "real_time_factor": round(res["ticks"] / 20 / wall, 3), "aborted": res["aborted"],
           "abort_reason": res["abort_reason"], "catchup_ticks": res["catchup_ticks"],
           "look_resets": gt["backend"].get("look_resets"), "bots": bots,
           "blocks": len(gt["blocks"]["tick"]), "hits": len(gt["hits"]["tick"]),
           "summary": gt["backend"].get("summary", {})}
    if is_eval:
        row["eval_metadata"] = gt["episode_info"]["Alpha"]["eval_metadata"]
        row["queries"] = [{"bots": list(q.bots), "frames": list(q.frames), "expected": q.expected, "frame1": q.frame1}
                          for q in ep.query_frames(episode_type, records)]
        row["eval_ids"] = ep.eval_ids_row(episode, records["Alpha"], records["Bravo"])
    return row


def main(argv=None) -> int:
    from solaris_env.engine.minecraft.collect import EVAL_TYPES, TRAINING_TYPES, MinecraftSession
    from solaris_env.engine.minecraft.install import setup_problem

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--types", nargs="+", default=list(TRAINING_TYPES) + list(EVAL_TYPES),
                   choices=list(TRAINING_TYPES) + list(EVAL_TYPES))
    p.add_argument("--episode", type=int, default=0, help="episode number (eval roles and cases depend on it)")
    p.add_argument("--resolution", type=int, default=96, help="square frame size written to the mp4s")
    p.add_argument("--out", default="/tmp/minecraft_recording", help="scratch dataset directory")
    p.add_argument("--results", default=str(RESULTS))
    args = p.parse_args(argv)
    problem = setup_problem()
    if problem:
        raise SystemExit(f"the Minecraft backend is not set up: {problem}")
    rows = []
    with MinecraftSession() as session:
        for t in args.types:
            load = os.getloadavg()[0]
            try:
                row = record_type(session, Path(args.out), t, args.episode, args.resolution)
            except Exception as e:  # noqa: BLE001 - reported in the table, the run goes on
                row = {"type": t, "error": f"{type(e).__name__}: {e}"[-2000:]}
            row["load_1min_before"] = round(load, 2)
            rows.append(row)
            print(json.dumps({k: row.get(k) for k in ("type", "ticks", "wall_s", "aborted", "error")}), file=sys.stderr)
    summary = {"types": len(rows), "recorded": sum("error" not in r for r in rows),
               "frames_equal_records": all(b["frames_equal_records"] for r in rows for b in r.get("bots", {}).values()),
               "ticks": sum(r.get("ticks", 0) for r in rows), "wall_s": round(sum(r.get("wall_s", 0) for r in rows), 1),
               "resolution": args.resolution, "cpu_count": os.cpu_count()}
    Path(args.results).write_text(json.dumps({"summary": summary, "rows": rows}, indent=1) + "\n")
    print(json.dumps(summary), file=sys.stderr)
    return 0 if summary["recorded"] == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
