#!/bin/bash
# Behaviour kept (issue 26): one scene solved by two source trees back to back, the BEFORE
# tree's scene file in both, `ndf-sim --quick --precision f64 -v`, one thread, nice 10,
# /usr/bin/time (user, sys, wall, peak KiB) and the 1-minute load average at start and end
# in WORK/log.txt. Compare the outputs with benchmarks/behaviour_kept_compare.py.
#
#   git archive 8b3c748 | tar -x -C WORK/before; git archive 8b3c5a5 | tar -x -C WORK/after
#   WORK=/tmp/b26w PYTHON=.venv/bin/python benchmarks/behaviour_kept.sh spline 900 napkin bowl
#
# usage: behaviour_kept.sh FIELD CPU_CAP_SECONDS SCENE...   (TREES="after" runs one tree;
# NICE=0 runs at the default priority instead of nice 10; SCENES=DIR takes SCENE.toml from DIR
# instead of WORK/before/scenes, e.g. a variant of a scene)
# A run over CPU_CAP_SECONDS of CPU is stopped by `ulimit -t` (compare what both reached in
# WORK/out/SCENE_FIELD_TREE.log). --no-pictures is passed to the after tree only (the
# before tree has no such flag; pictures change no number).
set -u
field=$1; cap=$2; shift 2
WORK=${WORK:?WORK: the folder holding before/ and after/}
PYTHON=${PYTHON:-python}
mkdir -p "$WORK/out"
for s in "$@"; do
 for tree in ${TREES:-before after}; do
  o=$WORK/out/${s}_${field}_${tree}
  rm -rf "$o" "$o.incomplete"
  echo "$s $field $tree start $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$WORK/log.txt"
  extra=""; [ "$tree" = after ] && extra="--no-pictures"
  ( ulimit -t "$cap"; cd "$WORK/$tree" && OMP_NUM_THREADS=1 PYTHONPATH="$WORK/$tree" nice -n "${NICE:-10}" \
      /usr/bin/time -f '%U %S %e %M' -o "$o.time" "$PYTHON" -m taichi_ndf.cli.sim \
      "${SCENES:-$WORK/before/scenes}/$s.toml" --field "$field" --quick --precision f64 $extra -v \
      --out "$o" > "$o.log" 2>&1; echo "rc $?" >> "$o.time" )
  echo "$s $field $tree end $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg) time $(tr '\n' ' ' < "$o.time")" >> "$WORK/log.txt"
 done
done
