#!/usr/bin/env bash
# Run mercury-dem on a SLURM or PBS cluster: the Dask scheduler runs here (a login node, or a
# small long job: see driver.* in cluster/slurm/ and cluster/pbs/), the workers run as batch
# jobs shaped by mercury_dem/cluster/KIND.yaml (the package defaults), and 'mercury-dem run' drives the pipeline.
#
#   cluster/common/launch_jobqueue.sh {slurm|pbs} MISSION RUN [--jobs N | --adapt MIN:MAX] [--no-tls]
#       [--tls-dir D] [--scheduler-host H] [--wait-workers K] [-- EXTRA mercury-dem run ARGS]
#   (cluster/slurm/launch.sh and cluster/pbs/launch.sh call this with their KIND.)
#
# Writes RUN (the run store) and RUN.dask/ (scheduler.json, logs/, tls/; override with
# DASK_DIR=...). Environment: PYTHON (default python3: the project's venv), MERCURY_DEM
# (default mercury-dem), DASK_CONFIG (a site YAML overriding the package defaults). TLS is on.
# The dashboard binds to 127.0.0.1:8787 here: ssh -L 8787:127.0.0.1:8787 THIS-HOST.
# The run resumes when launched again with the same MISSION and RUN.
set -euo pipefail

common="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
cluster="$(dirname "$common")"
usage() { sed -n '2,14p' "$common/launch_jobqueue.sh" | sed 's/^# \{0,1\}//'; exit "${1:-2}"; }
[ $# -ge 1 ] || usage
case "$1" in
  -h|--help) usage 0 ;;
  slurm) kind=slurm; system=SLURM; submit=sbatch ;;
  pbs)   kind=pbs;   system=PBS;   submit=qsub ;;
  *) echo "launch_jobqueue.sh: the first argument is the batch system, slurm or pbs, not '$1'" >&2; exit 2 ;;
esac
shift
[ $# -ge 1 ] || usage
case "$1" in -h|--help) usage 0 ;; esac
[ $# -ge 2 ] || usage
mission="$1"; run="${2%/}"; shift 2
launcher_args=(); run_args=()
while [ $# -gt 0 ]; do
  if [ "$1" = "--" ]; then shift; run_args=("$@"); break; fi
  launcher_args+=("$1"); shift
done

PYTHON="${PYTHON:-$(command -v python3 || command -v python)}"
MERCURY_DEM="${MERCURY_DEM:-mercury-dem}"
command -v "$MERCURY_DEM" >/dev/null || {
  echo "launch: $MERCURY_DEM is not on PATH; activate the project's venv or set MERCURY_DEM=/path/to/mercury-dem" >&2; exit 1; }
command -v "$submit" >/dev/null || { echo "launch: $submit not found: is this a $system login node?" >&2; exit 1; }
[ -e "$mission" ] || { echo "launch: mission $mission does not exist (make one with mercury-dem synth)" >&2; exit 1; }

dask_dir="${DASK_DIR:-$run.dask}"
# The job shape: the package's mercury_dem/cluster/KIND.yaml, overridden by any DASK_CONFIG YAML or DASK_JOBQUEUE__* variable.
exec "$PYTHON" "$cluster/jobqueue_launch.py" "$kind" --dask-dir "$dask_dir" "${launcher_args[@]+"${launcher_args[@]}"}" -- \
  "$MERCURY_DEM" run "$mission" --out "$run" --scheduler-file "$dask_dir/scheduler.json" "${run_args[@]+"${run_args[@]}"}"
