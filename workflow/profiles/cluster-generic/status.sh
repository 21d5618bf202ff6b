#!/usr/bin/env bash
# Status of a job started by submit.sh: prints exactly one of running, success, failed.
set -uo pipefail
id="$1"
dir="${CALIB_CLUSTER_DIR:-.snakemake/cluster-generic}"
if [[ ! -f "$dir/$id.submitted" ]]; then
    echo "status.sh: unknown job id '$id' (no $dir/$id.submitted)" >&2
    echo failed
    exit 0
fi
exit_code() { [[ -f "$dir/$id.exit" ]] && { [[ "$(cat "$dir/$id.exit")" == 0 ]] && echo success || echo failed; }; }
exit_code && exit 0
if [[ -f "$dir/$id.pid" ]]; then
    if kill -0 "$(cat "$dir/$id.pid")" 2> /dev/null; then
        echo running
        exit 0
    fi
    sleep 1  # the job may have ended between the two checks
    exit_code && exit 0
    echo failed  # gone without an exit code (killed)
    exit 0
fi
# submitted but not started yet: running for up to a minute, then failed
age=$(( $(date +%s) - $(stat -c %Y "$dir/$id.submitted") ))
if (( age > 60 )); then echo failed; else echo running; fi
