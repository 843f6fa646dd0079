#!/usr/bin/env bash
# Start a Dask scheduler and N workers on this machine, bound to 127.0.0.1, and record their PIDs.
#
#   cluster/local/start.sh [--workers N] [--threads T] [--memory-limit 4GiB] [--state-dir DIR]
#                          [--host 127.0.0.1] [--port 8786] [--dashboard-port 8787]
#                          [--tls | --tls-dir CERTDIR] [--timeout 60] [--idle-timeout SECONDS]
#
# DIR (default ./dask-local) receives:
#   scheduler.json   the scheduler file: mercury-dem run MISSION --out RUN --scheduler-file DIR/scheduler.json
#   pids/*.pid       one PID per process started (each leads its own process group); stop.sh reads them
#   logs/*.log       scheduler and worker logs;  workers/  the workers' local directory
#   env.sh           with --tls: 'source DIR/env.sh' gives any Dask client the certificates
# Every worker gets the resource adjust_slots=1, so the memory-heavy bundle adjustments
# run one at a time per worker. Port 0 picks free ports (the scheduler file has them).
# --tls uses DIR/tls (made by make-certs.sh when absent); --tls-dir uses CERTDIR
# (ca.pem, cert.pem, key.pem; made there when absent). With TLS every connection is
# encrypted and a client without a certificate signed by the CA is refused.
# --idle-timeout closes the scheduler after SECONDS with no task and no client connected, counted
# from the first worker or client that joined (not from the scheduler's start: a first worker on a
# cold machine can take longer than that to import); if nobody joins at all, it closes --timeout +
# SECONDS after its start. Its workers then exit after their 60 s death timeout. For throw-away
# deployments such as a test's, which must not outlive a killed caller. Off by default.
# (mercury_dem/cluster/idle_timeout.py, a scheduler preload that needs only distributed.)
# start.sh's own helpers end with it: if it fails or is interrupted (INT, TERM, HUP) before the
# workers joined, it stops what it started; its wait for the workers is bounded by 2 x --timeout.
# Stop everything with: cluster/local/stop.sh --state-dir DIR
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
usage() { sed -n '2,26p' "$0" | sed 's/^# \{0,1\}//'; exit "${1:-2}"; }

PYTHON="${PYTHON:-$(command -v python3 || command -v python)}"
workers=2; threads=1; memory_limit=""; state="./dask-local"; host="127.0.0.1"; port=8786; dport=8787
tls=0; tls_dir=""; timeout=60; idle_timeout=""
while [ $# -gt 0 ]; do
  case "$1" in
    --workers) workers="$2"; shift 2 ;;
    --threads) threads="$2"; shift 2 ;;
    --memory-limit) memory_limit="$2"; shift 2 ;;
    --state-dir) state="$2"; shift 2 ;;
    --host) host="$2"; shift 2 ;;
    --port) port="$2"; shift 2 ;;
    --dashboard-port) dport="$2"; shift 2 ;;
    --tls) tls=1; shift ;;
    --tls-dir) tls=1; tls_dir="$2"; shift 2 ;;
    --timeout) timeout="$2"; shift 2 ;;
    --idle-timeout) idle_timeout="$2"; shift 2 ;;
    -h|--help) usage 0 ;;
    *) echo "start.sh: unknown argument $1" >&2; usage ;;
  esac
done
idle_args=()
if [ -n "$idle_timeout" ]; then
  [[ "$idle_timeout" =~ ^[1-9][0-9]*$ ]] || { echo "start.sh: --idle-timeout must be a positive number of seconds, got $idle_timeout" >&2; exit 2; }
fi
[[ "$workers" =~ ^[1-9][0-9]*$ ]] || { echo "start.sh: --workers must be a positive integer, got $workers" >&2; exit 2; }
[[ "$timeout" =~ ^[1-9][0-9]*$ ]] || { echo "start.sh: --timeout must be a positive number of seconds, got $timeout" >&2; exit 2; }
if [ -n "$idle_timeout" ]; then
  # Dask's own --idle-timeout counts from the scheduler's start: this preload counts from the first join.
  idle_args=(--preload "$here/../../mercury_dem/cluster/idle_timeout.py"
             --idle-after-join "$idle_timeout" --join-bound "$(( timeout + idle_timeout ))")
fi
"$PYTHON" -c "import distributed" 2>/dev/null || {
  echo "start.sh: $PYTHON cannot import distributed; set PYTHON=/path/to/.venv/bin/python" >&2; exit 1; }

mkdir -p "$state/pids" "$state/logs" "$state/workers"
state="$(cd "$state" && pwd)"
for f in "$state"/pids/*.pid; do
  [ -e "$f" ] || continue
  if kill -0 "$(cat "$f")" 2>/dev/null; then
    echo "start.sh: $state already has a running process ($(basename "$f" .pid), PID $(cat "$f")); run stop.sh --state-dir $state first" >&2
    exit 1
  fi
  rm -f "$f"
done
sched_file="$state/scheduler.json"
rm -f "$sched_file" "$state/env.sh"

# From here on the processes in $state/pids are this run's: if start.sh fails or is interrupted before
# every worker has joined, it stops them, and it never leaves its own helper (the wait below) behind.
helper=""; started=0
cleanup() {
  local rc=$?
  set +e  # (a failing command here must not end the cleanup: errexit applies inside traps too)
  trap - EXIT INT TERM HUP
  if [ -n "$helper" ] && kill -0 "$helper" 2>/dev/null; then kill "$helper" 2>/dev/null; wait "$helper" 2>/dev/null; fi
  if [ "$started" = 0 ]; then "$here/stop.sh" --state-dir "$state" >&2 || true; fi
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
trap 'exit 129' HUP

# Each worker gets an equal share of the machine's memory unless told otherwise.
if [ -z "$memory_limit" ]; then
  total_kb="$(awk '/^MemTotal:/ {print $2}' /proc/meminfo 2>/dev/null || echo 0)"
  if [ "${total_kb:-0}" -gt 0 ]; then memory_limit="$(( total_kb * 1024 / workers ))"; else memory_limit="auto"; fi
fi

tls_args=()
if [ "$tls" = 1 ]; then
  tls_dir="${tls_dir:-$state/tls}"
  [ -e "$tls_dir/key.pem" ] || "$here/make-certs.sh" "$tls_dir" --hosts "$host,localhost" >/dev/null
  tls_dir="$(cd "$tls_dir" && pwd)"
  tls_args=(--tls-ca-file "$tls_dir/ca.pem" --tls-cert "$tls_dir/cert.pem" --tls-key "$tls_dir/key.pem")
  cat > "$state/env.sh" <<ENV
# source this file: Dask clients (mercury-dem run, notebooks) then connect over TLS
export DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION=True
export DASK_DISTRIBUTED__COMM__TLS__CA_FILE="$tls_dir/ca.pem"
export DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT="$tls_dir/cert.pem"
export DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY="$tls_dir/key.pem"
ENV
  protocol=tls
else
  protocol=tcp
fi

# setsid: each process leads its own process group, so stop.sh can end it and its
# children (a worker's nanny and worker process) by that one recorded PID. (Without setsid,
# e.g. on macOS, stop.sh signals the PID alone; the nanny still ends its worker.)
SETSID="$(command -v setsid || true)"
$SETSID "$PYTHON" -m distributed.cli.dask_scheduler \
  --host "$host" --port "$port" --protocol "$protocol" --dashboard-address "$host:$dport" \
  --scheduler-file "$sched_file" "${tls_args[@]}" ${idle_args[@]+"${idle_args[@]}"} \
  >"$state/logs/scheduler.log" 2>&1 < /dev/null &
echo $! > "$state/pids/scheduler.pid"

# Workers start at once: each waits (up to its death timeout) for the scheduler file.
for i in $(seq 1 "$workers"); do
  $SETSID "$PYTHON" -m distributed.cli.dask_worker \
    --scheduler-file "$sched_file" --host "$host" --dashboard-address "$host:0" \
    --nthreads "$threads" --nworkers 1 --memory-limit "$memory_limit" --resources "adjust_slots=1" \
    --name "local-$i" --local-directory "$state/workers" --death-timeout 60 "${tls_args[@]}" \
    >"$state/logs/worker-$i.log" 2>&1 < /dev/null &
  echo $! > "$state/pids/worker-$i.pid"
done

for _ in $(seq 1 $(( timeout * 10 ))); do
  [ -s "$sched_file" ] && break
  if ! kill -0 "$(cat "$state/pids/scheduler.pid")" 2>/dev/null; then
    echo "start.sh: the scheduler exited; see $state/logs/scheduler.log:" >&2; tail -5 "$state/logs/scheduler.log" >&2
    exit 1  # cleanup stops the workers
  fi
  sleep 0.1
done
[ -s "$sched_file" ] || { echo "start.sh: no scheduler file after ${timeout}s; see $state/logs/scheduler.log" >&2; exit 1; }

# Wait until every worker has joined (a client with the same certificates). In the background, so a
# signal to start.sh is handled at once (bash defers traps while a foreground child runs); the helper
# also ends itself after 2 x --timeout whatever happens (a connection retrying, a hung close).
"$PYTHON" - "$sched_file" "$workers" "$timeout" "${tls_dir:-}" <<'PY' &
import os
import sys
import threading
import time


def _deadline(limit: float) -> None:
    time.sleep(limit)
    print(f"start.sh: the wait for the workers did not end within {limit:.0f}s", file=sys.stderr, flush=True)
    os._exit(3)


sched_file, n, timeout, tls_dir = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
threading.Thread(target=_deadline, args=(2 * timeout,), daemon=True).start()
from distributed import Client  # noqa: E402
from distributed.security import Security  # noqa: E402

sec = None
if tls_dir:
    ca, cert, key = (f"{tls_dir}/{n_}" for n_ in ("ca.pem", "cert.pem", "key.pem"))
    sec = Security(tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key, require_encryption=True)
with Client(scheduler_file=sched_file, security=sec, timeout=timeout) as c:
    c.wait_for_workers(n, timeout=timeout)
    info = c.scheduler_info(n_workers=-1)
    print(f"scheduler {info['address']}  workers {len(info['workers'])}  dashboard {c.dashboard_link}")
PY
helper=$!
if ! wait "$helper"; then
  helper=""
  echo "start.sh: the workers did not all join within ${timeout}s; see $state/logs/; stopping" >&2
  exit 1  # cleanup stops what was started
fi
helper=""; started=1
echo "scheduler file: $sched_file"
[ "$tls" = 1 ] && echo "TLS: source $state/env.sh before connecting (or pass --tls-ca-file/--tls-cert/--tls-key)"
echo "stop with: $here/stop.sh --state-dir $state"
