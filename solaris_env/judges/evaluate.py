"""Score recorded eval episodes with a judge, episode-level as the paper (docs/engine.md §7.5).

    python -m solaris_env.judges.evaluate --data DIR                       # the shipped probes
    python -m solaris_env.judges.evaluate --data DIR --judge vlm --endpoint http://host:8000 --model NAME

``DIR`` is a ``solaris-engine collect --eval`` output; every query of docs/engine.md §7.2 is asked about
the ground-truth videos. Prints (and with ``--out`` writes) per eval type the episode-level accuracy
and per task (Movement, Grounding, Memory, Building, Consistency) the mean over its types.
The VLM judge reads its API key, if any, from the environment variable named by ``--api-key-env``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from solaris_env.engine.eval_protocol import EVAL_KEYS
from solaris_env.judges.episodes import find_episodes
from solaris_env.judges.judge import DEFAULT_WEIGHTS, Judge
from solaris_env.judges.scoring import episode_accuracy, judge_episodes, task_accuracy
from solaris_env.judges.vlm import VLMConfig, VLMJudge
from solaris_env.paths import portable_path

JUDGES = ("probe", "vlm")


def make_judge(args):
    """The judge named by ``--judge``: the probes from ``--weights`` or a VLM at ``--endpoint``."""
    if args.judge == "probe":
        return Judge.load(args.weights)
    if not args.endpoint:
        raise SystemExit("--judge vlm needs --endpoint URL")
    return VLMJudge(VLMConfig(endpoint=args.endpoint, model=args.model, api_key=os.environ.get(args.api_key_env)))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m solaris_env.judges.evaluate", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="a solaris-engine collect --eval output")
    p.add_argument("--judge", choices=JUDGES, default="probe", help="probe (default, offline) or vlm")
    p.add_argument("--weights", default=str(DEFAULT_WEIGHTS), help="probe: directory of <question>.safetensors")
    p.add_argument("--endpoint", default=None, help="vlm: OpenAI-compatible server URL")
    p.add_argument("--model", default=VLMConfig.__dataclass_fields__["model"].default, help="vlm: model name")
    p.add_argument("--api-key-env", default="SOLARIS_JUDGE_API_KEY", help="vlm: env variable holding the API key")
    p.add_argument("--types", nargs="+", default=None, choices=sorted(EVAL_KEYS), help="only these eval types")
    p.add_argument("--out", default=None, help="write the results as JSON here")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    judge = make_judge(args)
    episodes = [e for e in find_episodes(args.data, args.types) if e.is_eval]
    if not episodes:
        raise SystemExit(f"no eval episodes under {args.data}")
    results = judge_episodes(judge, episodes)
    per_type = episode_accuracy(results)
    report = {"data": portable_path(args.data), "judge": args.judge, "episode_level": per_type,
              "tasks": task_accuracy(per_type)}
    for etype, s in per_type.items():
        print(f"{etype:24s} episodes {s['episodes']:3d}  accuracy {100 * s['accuracy']:6.2f} %  "
              f"(queries {100 * s['query_accuracy']:6.2f} %, unanswered {s['unanswered']})")
    for task, acc in report["tasks"].items():
        print(f"{task:24s} {100 * acc:6.2f} %")
    if args.out:
        out = Path(args.out)
        tmp = out.with_name(f".{out.name}.tmp")
        tmp.write_text(json.dumps(report, indent=2))
        os.replace(tmp, out)
        print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
