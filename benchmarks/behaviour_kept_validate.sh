#!/bin/bash
# Behaviour kept (issue 26): `ndf-validate` run by the two source trees of behaviour_kept.sh
# (WORK/before, WORK/after), the BEFORE tree's validation scenes in both, one thread, f64,
# /usr/bin/time (user, sys, wall, peak KiB) and the 1-minute load average at start and end in
# WORK/log.txt. Outputs: WORK/val/TAG_TREE/ (results.json, results.md) and TAG_TREE.{log,time}.
#
#   WORK=/tmp/b26w PYTHON=.venv/bin/python benchmarks/behaviour_kept_validate.sh \
#       spline_full 3000 --field spline pinched_cylinder
#
# usage: behaviour_kept_validate.sh TAG CPU_CAP_SECONDS ARGS...   (ARGS go to ndf-validate:
# --field, --quick, --seed, case names; TREES="after" runs one tree, NICE as behaviour_kept.sh)
set -u
tag=$1; cap=$2; shift 2
WORK=${WORK:?WORK: the folder holding before/ and after/}
PYTHON=${PYTHON:-python}
mkdir -p "$WORK/val"
for tree in ${TREES:-before after}; do
  o=$WORK/val/${tag}_${tree}
  rm -rf "$o"
  echo "validate $tag $tree start $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$WORK/log.txt"
  ( ulimit -t "$cap"; cd "$WORK/$tree" && OMP_NUM_THREADS=1 PYTHONPATH="$WORK/$tree" nice -n "${NICE:-10}" \
      /usr/bin/time -f '%U %S %e %M' -o "$o.time" "$PYTHON" -m taichi_ndf.cli.validate "$@" \
      --precision f64 --scenes "$WORK/before/validation/scenes" --out "$o" > "$o.log" 2>&1
    echo "rc $?" >> "$o.time" )
  echo "validate $tag $tree end $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg) time $(tr '\n' ' ' < "$o.time")" >> "$WORK/log.txt"
done
