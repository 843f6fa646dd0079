#!/usr/bin/env bash
# Stop what start.sh started, by the PIDs it recorded (workers first, then the scheduler).
#
#   cluster/local/stop.sh [--state-dir DIR] [--timeout 20]
#
# Each recorded PID leads a process group (start.sh used setsid); the group gets SIGTERM
# (a nanny then closes its worker cleanly), and SIGKILL after --timeout seconds.
# Only PIDs whose command line is a Dask scheduler/worker are signalled (a stale PID
# file whose number was reused by another program is skipped). Exit 1 if any survive.
set -uo pipefail

state="./dask-local"; timeout=20
while [ $# -gt 0 ]; do
  case "$1" in
    --state-dir) state="$2"; shift 2 ;;
    --timeout) timeout="$2"; shift 2 ;;
    -h|--help) sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "stop.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
[ -d "$state/pids" ] || { echo "stop.sh: nothing recorded in $state/pids"; exit 0; }

is_dask() { ps -o args= -p "$1" 2>/dev/null | grep -q 'distributed.cli.dask_\|dask scheduler\|dask worker'; }
# The process group the PID leads (start.sh used setsid), or the PID alone where setsid was missing.
group_alive() { kill -0 -- "-$1" 2>/dev/null || kill -0 "$1" 2>/dev/null; }
group_is_dask() {  # a member of process group $1 is a Dask process or one of its multiprocessing children
  local p
  for p in $(pgrep -g "$1" 2>/dev/null); do
    is_dask "$p" && return 0
    ps -o args= -p "$p" 2>/dev/null | grep -q 'multiprocessing.spawn\|multiprocessing.resource_tracker' && return 0
  done
  return 1
}
kill_group() { kill "-$1" -- "-$2" 2>/dev/null || kill "-$1" "$2" 2>/dev/null; }

stop_files() {
  local pids=() f pid
  for f in "$@"; do
    [ -e "$f" ] || continue
    pid="$(cat "$f")"
    [[ "$pid" =~ ^[0-9]+$ ]] || continue
    if kill -0 "$pid" 2>/dev/null && is_dask "$pid"; then
      kill -TERM "$pid" 2>/dev/null && pids+=("$pid")       # the leader: a nanny closes its worker
    elif group_is_dask "$pid"; then
      kill_group TERM "$pid" && pids+=("$pid")             # leader gone, its children left behind
    fi
  done
  local waited=0
  while [ "${#pids[@]}" -gt 0 ] && [ "$waited" -lt $(( timeout * 10 )) ]; do
    local left=()
    for pid in "${pids[@]}"; do group_alive "$pid" && left+=("$pid"); done
    pids=("${left[@]+"${left[@]}"}")
    [ "${#pids[@]}" -gt 0 ] || break
    sleep 0.1; waited=$(( waited + 1 ))
  done
  for pid in "${pids[@]+"${pids[@]}"}"; do
    echo "stop.sh: process group $pid did not exit after ${timeout}s; killing" >&2
    kill_group KILL "$pid"
  done
  for f in "$@"; do [ -e "$f" ] && rm -f "$f"; done
}

stop_files "$state"/pids/worker-*.pid
stop_files "$state"/pids/scheduler.pid
sleep 0.2
survivors=0
for f in "$state"/pids/*.pid; do [ -e "$f" ] && survivors=1; done
rm -f "$state/scheduler.json"
[ "$survivors" = 0 ] && echo "stopped the Dask processes recorded in $state/pids" && exit 0
exit 1
