#!/bin/bash
# stars --delta 0.5 on the finger box on 2 local dask workers, everything at nice 19, logged:
#   bash benchmarks/run_delta05.sh OUTDIR [WORKERS]
# (benchmarks/run_cluster.sh says what it logs.)  Read the figures with:
#   python benchmarks/bench_scale.py progress OUTDIR
exec bash "$(dirname "$0")/run_cluster.sh" "${1:?OUTDIR}" "${2:-2}" stars --delta 0.5
