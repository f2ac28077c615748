#!/usr/bin/env bash
# The GPU session's one call (docs/training.md, "The GPU session: one call"): two sprints side by side on the one
# GPU, for the same wall-clock budget,
#   $OUT/sprint/   the candidate: SPRINT_INIT (default: the shipped model) continued by `solaris-train sprint`;
#   $OUT/control/  the control row (issue 23 §4): SPRINT_INIT's codec and image encoder under a fresh DiT in the
#                  official layout (`solaris-train official-dit`), trained by the same sprint for the time left.
# Each comes back as model/weights-*.safetensors plus meta.tar (log.txt, model/config.json, model/lineage.json):
# a tiny16 model is 3 shards of at most 16 MiB, so the two make 8 files, the device tool's limit. Until the end
# the candidate writes into $OUT/sprint unpacked (at most 6 files), so a call killed at its limit still returns it.
#
# Run from the repository root: `bash training/gpu_call.sh` with OUT set. Settings (environment):
#   PYTHON (python3), SPRINT_PRESET (tiny16), SPRINT_INIT (default), SPRINT_BUDGET_MIN (8.5; from this script's
#   start), SPRINT_WORKERS (collect workers per sprint; (cores - 4) / 2, at least 1), SPRINT_DATA (a folder
#   holding sprint/ and control/, each a dataset root to record into; default: each sprint's own temporary one),
#   XLA_PYTHON_CLIENT_MEM_FRACTION (0.45: two JAX processes share the GPU's memory).
# Wheels in .whl/ (the Farama packages the machine lacks) are installed into a temporary folder first (unpacked
# as zip files where the interpreter has no pip).
# Exit status: the candidate's sprint's (the control's is printed).
set -u
: "${OUT:?OUT must name the folder that comes back}"
PY=${PYTHON:-python3}
PRESET=${SPRINT_PRESET:-tiny16}
INIT=${SPRINT_INIT:-default}
MIN=${SPRINT_BUDGET_MIN:-8.5}
start=$(date +%s)
K=$(mktemp -d "${TMPDIR:-/tmp}/solaris-call.XXXXXX")
if compgen -G ".whl/*.whl" > /dev/null; then
  "$PY" -m pip install -q --no-index --no-deps --target "$K/site" .whl/*.whl 2> /dev/null \
    || for w in .whl/*.whl; do "$PY" -m zipfile -e "$w" "$K/site" || { echo "gpu_call: cannot unpack $w"; exit 3; }; done
fi
export PYTHONPATH="$K/site:$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.45}
cores=$(nproc)
W=${SPRINT_WORKERS:-$(( cores > 5 ? (cores - 4) / 2 : 1 ))}
main_data=() ctl_data=()
[ -n "${SPRINT_DATA:-}" ] && main_data=(--data "$SPRINT_DATA/sprint") ctl_data=(--data "$SPRINT_DATA/control")

minutes_left() { awk -v m="$MIN" -v s="$start" -v n="$(date +%s)" 'BEGIN { printf "%.3f", m - (n - s) / 60 }'; }

mkdir -p "$OUT/sprint"
"$PY" -m training.cli sprint --preset "$PRESET" --init "$INIT" --out "$OUT/sprint" --budget-min "$(minutes_left)" \
  --workers "$W" "${main_data[@]}" > "$OUT/sprint/log.txt" 2>&1 &
main=$!
(
  "$PY" -m training.cli official-dit "$INIT" --out "$K/control-init" || exit $?
  exec "$PY" -m training.cli sprint --preset "$PRESET" --init "$K/control-init" --out "$K/control" \
    --budget-min "$(minutes_left)" --workers "$W" "${ctl_data[@]}"
) > "$K/control.log" 2>&1 &
ctl=$!
wait "$main"; rc=$?
wait "$ctl"; crc=$?
cp "$OUT/sprint/log.txt" "$K/sprint.log"

pack() {  # $1: a run folder holding model/ and log.txt -> its shards + meta.tar
  tar -C "$1" -cf "$1/meta.tar" log.txt model/config.json model/lineage.json \
    && rm -f "$1/log.txt" "$1/model/config.json" "$1/model/lineage.json"
}
# only two finished models fit the 8 files packed; otherwise the candidate's folder stays as it is
if [ "$rc" -eq 0 ] && [ "$crc" -eq 0 ] && [ -d "$K/control/model" ]; then
  mkdir -p "$OUT/control" && mv "$K/control/model" "$OUT/control/model" && cp "$K/control.log" "$OUT/control/log.txt" \
    && pack "$OUT/control" && pack "$OUT/sprint"
fi
for run in sprint control; do
  log="$K/$run.log"
  echo "== $run: exit $([ "$run" = sprint ] && echo "$rc" || echo "$crc")"
  grep -a "sprint:\|Error\|error:" "$log" | tail -n 14
done
[ -f "$OUT/sprint/meta.tar" ] && echo "gpu_call: both packed; unpack with: tar -C DIR -xf DIR/meta.tar"
rm -rf "$K"
exit "$rc"
