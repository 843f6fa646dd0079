#!/usr/bin/env bash
# Interleaved A/B of the tile-matching stage: the code at commit OLD against the working tree, on the tiny
# mission each generates in its own store format, REPEATS times each, in one lock hold; then checks that the
# two runs' tile networks are identical. Usage: workflows/benchmarks/ab_tile_stage.sh OLD [REPEATS]
set -euo pipefail
OLD=${1:?usage: ab_tile_stage.sh OLD_COMMIT [REPEATS]}
REPEATS=${2:-3}
top=$(git rev-parse --show-toplevel)
PY=$top/.venv/bin/python
work=$(mktemp -d /tmp/ab_tile.XXXX)
git -C "$top" worktree add --detach "$work/old" "$OLD" >/dev/null
trap 'git -C "$top" worktree remove --force "$work/old"' EXIT
run() {  # side src mission out
  (cd "$2" && PYTHONPATH="$2" "$PY" -c "from mercury_dem.cli import main; import sys; sys.exit(main(sys.argv[1:]))" "${@:3}")
}
run old "$work/old" synth "$work/old_m" --preset tiny --workers 2 >/dev/null
run new "$top" synth "$work/new_m" --preset tiny --workers 2 >/dev/null
exec 9>/tmp/mercury_bench.lock
flock 9
for rep in $(seq "$REPEATS"); do
  for side in old new; do
    src=$top; [ "$side" = old ] && src=$work/old
    rm -rf "$work/run_$side"
    s=$(date +%s.%N)
    run "$side" "$src" match "$work/${side}_m" --out "$work/run_$side" >/dev/null
    e=$(date +%s.%N)
    echo "repeat $rep $side $(echo "$e - $s" | bc) s"
  done
done
"$PY" - "$work" <<'PYEOF'
import glob, sys
import numpy as np
from mercury_dem.network.store import read_network
work = sys.argv[1]
n = bad = 0
for d in sorted(glob.glob(f"{work}/run_new/tile/*/network.zarr")):
    a, b = read_network(d), read_network(d.replace("run_new", "run_old"))
    for k in ("sample", "line", "apriori_xyz", "measure_point", "measure_image", "image_ids", "point_ids", "sigma"):
        x, y = np.asarray(getattr(a, k)), np.asarray(getattr(b, k))
        n += 1
        same = np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f" else np.array_equal(x, y)
        bad += not same
print(f"{n} tile-network arrays compared, {bad} differ")
PYEOF
