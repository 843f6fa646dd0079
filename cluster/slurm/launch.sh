#!/usr/bin/env bash
# Run mercury-dem on a SLURM cluster: scheduler here, workers as SLURM batch jobs shaped by
# mercury_dem/cluster/KIND.yaml (site overrides: DASK_CONFIG), then 'mercury-dem run --scheduler-file'.
#
#   cluster/slurm/launch.sh MISSION RUN [--jobs N | --adapt MIN:MAX] [--no-tls] [--tls-dir D]
#                        [--scheduler-host H] [--wait-workers K] [-- EXTRA mercury-dem run ARGS]
#
# The launcher is shared with the other batch system: cluster/common/launch_jobqueue.sh
# (its header lists the environment variables and what is written where).
exec "$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)/../common/launch_jobqueue.sh" slurm "$@"
