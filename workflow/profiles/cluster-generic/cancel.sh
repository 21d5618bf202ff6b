#!/usr/bin/env bash
# Cancel jobs started by submit.sh: end each job's process group (by the id recorded at submission).
set -uo pipefail
dir="${CALIB_CLUSTER_DIR:-.snakemake/cluster-generic}"
for id in "$@"; do
    if [[ -f "$dir/$id.pid" ]]; then
        kill -TERM -- "-$(cat "$dir/$id.pid")" 2> /dev/null || true
    fi
done
exit 0
