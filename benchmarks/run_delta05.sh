#!/bin/bash
# stars --delta 0.5 on the finger box on 2 local dask workers, everything at nice 19, logged:
#   bash benchmarks/run_delta05.sh OUTDIR [WORKERS]
# OUTDIR/client.log: the command's progress lines; OUTDIR/sample.log: every 30 s the load and,
# per process (scheduler, worker processes, client), RSS, peak RSS (VmHWM) and CPU seconds.
# Read the figures with: python benchmarks/bench_scale.py progress OUTDIR
set -u
R=$(realpath "${1:?OUTDIR}"); W=${2:-2}; PORT=${PORT:-8799}
mkdir -p "$R"; rm -f "$R/end"
nice -n 19 dask scheduler --host 127.0.0.1 --port "$PORT" --no-dashboard > "$R/scheduler.log" 2>&1 &
echo $! > "$R/scheduler.pid"; sleep 4
nice -n 19 dask worker "tcp://127.0.0.1:$PORT" --nworkers "$W" --nthreads 1 --memory-limit 4GiB --no-dashboard \
    > "$R/workers.log" 2>&1 &
echo $! > "$R/workers.pid"; sleep 6
date -u +%FT%TZ > "$R/start"
nice -n 19 starforge --max-seconds 30000 --scheduler "tcp://127.0.0.1:$PORT" stars --delta 0.5 \
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
