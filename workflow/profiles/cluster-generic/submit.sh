#!/usr/bin/env bash
# Stand-in "scheduler" for the cluster-generic executor: run the job script (last argument) detached in the
# background on this machine and print its job id on the first line of stdout.
# State per job in $CALIB_CLUSTER_DIR (default .snakemake/cluster-generic): <id>.pid (process-group id),
# <id>.log (the job's stdout and stderr), <id>.exit (exit code, written when the job ends).
set -euo pipefail
jobscript="${!#}"
if [[ ! -f "$jobscript" ]]; then
    echo "submit.sh: job script '$jobscript' not found" >&2
    exit 2
fi
dir="${CALIB_CLUSTER_DIR:-.snakemake/cluster-generic}"
mkdir -p "$dir"
id="calib-$(date +%s)-$$-$RANDOM"
: > "$dir/$id.submitted"
# setsid: the job gets its own process group (cancel.sh ends the group); all three standard streams are
# redirected so that the executor, which reads this script's stdout, does not wait for the job.
setsid bash -c 'echo $$ > "$2/$3.pid.part" && mv "$2/$3.pid.part" "$2/$3.pid"
bash "$1" > "$2/$3.log" 2>&1
rc=$?
echo $rc > "$2/$3.exit.part" && mv "$2/$3.exit.part" "$2/$3.exit"' calib-job "$jobscript" "$dir" "$id" \
    < /dev/null > /dev/null 2>&1 &
echo "$id"
