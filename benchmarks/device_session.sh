#!/usr/bin/env bash
# One session's accelerator rows in one call, each part its own process with its own time
# limit, so that a slow or failing part costs only its own rows (a device is lent for
# minutes: benchmarks/results/device.md). Run from the repository root on the device:
#
#     OUT=/some/folder bash benchmarks/device_session.sh     # $OUT: where the logs go
#
# Parts, in the order of what is least measured (edit the limits to the time lent):
#   1. full-history sweeps at 32,768 curves with every branch computed for every lane
#      (JAXCONTACT_LANE_BRANCHES=0: the code before 2026-11-27 22:00 UTC), then
#   2. sweeps: relaxed summaries to 10^7 points, full histories at 32,768 curves, with
#      the branches no lane takes skipped (the default)
#   3. the history map with the default search, 512 curves, cold and warm
#   4. the README's main job, cold, no compilation cache
#   5. the history map's search on a 16-cell grid (`search_cells`), 512 curves, one call
#   6. the relaxed map: 4,096 curves (cold) and 16,384 (chunk compiled)
#   7. the history map at 512 curves with every branch computed (the baseline of 3)
set -u
export PYTHONPATH=. PYTHONUNBUFFERED=1 JAXCONTACT_NO_CACHE=1
OUT=${OUT:-device-logs}
mkdir -p "$OUT"
D=benchmarks/device_check.py
NONE=(--fit-curves "" --history-fit "" --sweep-max 0 --history "")
part() {  # part NAME SECONDS COMMAND...: run with a limit, log to $OUT/NAME.log
    local name=$1 limit=$2
    shift 2
    echo "== $name (limit ${limit} s) $(date -u +%H:%M:%S)"
    timeout "$limit" "$@" 2>&1 | tee "$OUT/$name.log"
    echo "== $name: exit ${PIPESTATUS[0]} $(date -u +%H:%M:%S)"
}
nvidia-smi -L 2>/dev/null
git log --oneline -1 2>/dev/null
part sweeps-all-branches ${LIMIT_SWEEPS_OFF:-60} env JAXCONTACT_LANE_BRANCHES=0 python $D \
    "${NONE[@]}" --history 32768 --repeats 1
part sweeps ${LIMIT_SWEEPS:-70} python $D "${NONE[@]}" --sweep-max 10000000 --history 32768 \
    --repeats 1
part history-default ${LIMIT_HISTORY:-160} python $D "${NONE[@]}" --history-fit 512 --repeats 1
part main-job ${LIMIT_MAIN:-100} python -m jaxcontact_cli fit \
    tests/data/oocyte-stress-relaxation-cell1-0008.jpk-force --profile sphere:40e-6 \
    --model history --out /tmp/main-job  # its files stay there: $OUT keeps the logs
part history-cells16 ${LIMIT_HISTORY_CELLS:-150} python $D "${NONE[@]}" --history-fit 512 \
    --history-options '{"search_cells": 16}' --repeats 0
part relaxed-map ${LIMIT_RELAXED:-120} python $D "${NONE[@]}" --fit-curves 4096,16384 \
    --baseline-workers 0 --repeats 0
part history-all-branches ${LIMIT_HISTORY_OFF:-160} env JAXCONTACT_LANE_BRANCHES=0 python $D \
    "${NONE[@]}" --history-fit 512 --repeats 1
