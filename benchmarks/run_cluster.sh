#!/bin/bash
# A starforge command on a local dask cluster started by hand (scheduler + worker processes), logged:
#   bash benchmarks/run_cluster.sh OUTDIR WORKERS STARFORGE-ARGS...
# e.g. bash benchmarks/run_cluster.sh /tmp/d05 2 stars --delta 0.5
#      bash benchmarks/run_cluster.sh /tmp/sw 2 sweep --exhaustive auto
# The command writes into OUTDIR/out.  NICE (default 19) sets every process's niceness.
# OUTDIR/client.log: the command's progress lines; OUTDIR/sample.log: every 30 s the load and,
# per process (scheduler, worker processes, client), RSS, peak RSS (VmHWM) and CPU seconds.
# Read the figures with: python benchmarks/bench_scale.py progress OUTDIR
set -u
R=$(realpath "${1:?OUTDIR}"); W=${2:?WORKERS}; shift 2; PORT=${PORT:-8799}; N=${NICE:-19}
mkdir -p "$R"; rm -f "$R/end"
printf '%s\n' "$@" > "$R/command"
nice -n "$N" dask scheduler --host 127.0.0.1 --port "$PORT" --no-dashboard > "$R/scheduler.log" 2>&1 &
echo $! > "$R/scheduler.pid"; sleep 4
nice -n "$N" dask worker "tcp://127.0.0.1:$PORT" --nworkers "$W" --nthreads 1 --memory-limit 4GiB --no-dashboard \
    > "$R/workers.log" 2>&1 &
echo $! > "$R/workers.pid"; sleep 6
date -u +%FT%TZ > "$R/start"
nice -n "$N" starforge --max-seconds 30000 --scheduler "tcp://127.0.0.1:$PORT" "$@" \
    --out "$R/out" --force > "$R/client.out" 2> "$R/client.log" &
echo $! > "$R/client.pid"
(
  while [ ! -f "$R/end" ]; do
    echo "== $(date -u +%T) load $(cut -d' ' -f1-3 /proc/loadavg)"
    for p in $(cat "$R/scheduler.pid") $(pgrep -P "$(cat "$R/workers.pid")" -f spawn_main) $(cat "$R/client.pid"); do
      [ -r "/proc/$p/status" ] || continue
      role=worker; [ "$p" = "$(cat "$R/scheduler.pid")" ] && role=scheduler; [ "$p" = "$(cat "$R/client.pid")" ] && role=client
      echo "$p $role rss_kb=$(awk '/VmRSS/{print $2}' /proc/$p/status) hwm_kb=$(awk '/VmHWM/{print $2}' /proc/$p/status)" \
           "cpu_s=$(awk '{printf "%.0f", ($14+$15)/100}' /proc/$p/stat)"
    done
    sleep 30
  done
) > "$R/sample.log" 2>&1 &
wait "$(cat "$R/client.pid")"; echo "exit $?" >> "$R/client.log"
date -u +%FT%TZ > "$R/end"
kill "$(cat "$R/workers.pid")" "$(cat "$R/scheduler.pid")"
