#!/usr/bin/env bash
# The .test study on a real one-node SLURM cluster, compared product by product with a local run.
#
#   sudo tools/slurm_cluster.sh        # Debian/Ubuntu, as root; CI runs it after `python3 run.py test`
#
# 1. installs slurm-wlm and munge with apt where they are missing;
# 2. starts a private one-node cluster: munged with its own key and socket, slurmctld and slurmd on ports 16817/16818
#    with /etc/slurm/slurm.conf written for this host (its name, CPUs and memory from `slurmd -C`; no accounting);
#    state, spool and logs in a temporary folder;
# 3. runs the .test study (.test/config.yaml) through workflow/profiles/slurm-small with no flags beyond the profile
#    (tools/slurm_run.py: the pre-flight check, then snakemake), then the same study locally
#    (workflow/profiles/default), both into the same results path one after the other (the path is part of the
#    products' configuration hash), each moved aside when done; .test/results is not touched;
# 4. compares every product with tools/hash_products.py --compare and prints the number of SLURM jobs (from
#    snakemake's log: accounting, hence sacct, is off) and the wall times.
# The daemons are stopped by their PIDs at the end, also on failure and Ctrl-C, and /etc/slurm/slurm.conf removed.
# Exit status: 0 (every product identical, or skipped: the one line "skipped: <reason>" says why), 1 otherwise.
# CALIB_SLURM_KEEP=1 keeps the temporary folder (logs, both results folders).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
MARK="# written by calib tools/slurm_cluster.sh"
CONF=/etc/slurm/slurm.conf

skip() { echo "skipped: $*"; exit 0; }
[ "$(uname -s)" = Linux ] || skip "not Linux"
[ "$(id -u)" -eq 0 ] || skip "not root (the script installs packages and starts the SLURM and munge daemons)"
command -v apt-get > /dev/null || skip "no apt-get (the script installs slurm-wlm and munge on Debian/Ubuntu)"
if [ -e "$CONF" ] && ! grep -qF "$MARK" "$CONF"; then
  skip "$CONF exists: this host has its own SLURM configuration, which the script leaves alone"
fi
T0=$SECONDS

if ! command -v slurmctld > /dev/null || ! command -v slurmd > /dev/null || ! command -v munged > /dev/null \
    || ! command -v sbatch > /dev/null; then
  echo "+ apt-get install slurm-wlm munge"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends slurm-wlm munge > /dev/null
fi
echo "$(slurmd -V), $(munged -V | cut -d' ' -f1)"

# the venv of run.py (CALIB_VENV, as in .ci/run) with the slurm extra
python3 run.py setup --slurm
VENV=${CALIB_VENV:-$ROOT/.venv}
export PATH="$VENV/bin:$PATH"

WORK=$(mktemp -d /tmp/calib-slurm.XXXXXX)
chmod 755 "$WORK"
mkdir -p "$WORK/munge" "$WORK/state" "$WORK/spool" "$WORK/log"
PIDS=()
cleanup() {
  rc=$?
  trap - EXIT INT TERM
  if [ ${#PIDS[@]} -gt 0 ]; then
    # jobs of this cluster only: cancelled, and their steps given up to 30 s to end, before the daemons stop
    scancel --quiet --user="$(id -un)" 2> /dev/null || true
    for _ in $(seq 60); do [ -z "$(squeue -h -o %i 2> /dev/null)" ] && break; sleep 0.5; done
    for ((i = ${#PIDS[@]} - 1; i >= 0; i--)); do kill "${PIDS[i]}" 2> /dev/null || true; done
    for pid in "${PIDS[@]}"; do
      for _ in $(seq 50); do kill -0 "$pid" 2> /dev/null || break; sleep 0.2; done
      kill -KILL "$pid" 2> /dev/null || true
    done
  fi
  if [ -e "$CONF" ] && grep -qF "$MARK" "$CONF"; then rm -f "$CONF"; fi
  if [ "$rc" -ne 0 ] && [ -f "$WORK/log/slurmctld.log" ]; then
    echo "---- last lines of slurmctld.log and slurmd.log ($WORK/log):"
    tail -n 15 "$WORK/log/slurmctld.log" "$WORK/log/slurmd.log" 2> /dev/null || true
  fi
  if [ "${CALIB_SLURM_KEEP:-0}" = 1 ] || [ "$rc" -ne 0 ]; then echo "kept: $WORK"; else rm -rf "$WORK"; fi
  echo "slurm_cluster: daemons stopped, exit $rc after $((SECONDS - T0)) s"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# The daemons run in sessions of their own (setsid execs them: $! is the daemon), so that a Ctrl-C reaches only
# snakemake, which then cancels its jobs while the cluster is still up; cleanup stops the daemons after that.
# munge: its own key and socket (a munged of the host, if any, is left alone)
if command -v mungekey > /dev/null; then
  mungekey --create --keyfile="$WORK/munge/munge.key"
else
  dd if=/dev/urandom of="$WORK/munge/munge.key" bs=1024 count=1 status=none
fi
chmod 600 "$WORK/munge/munge.key"
setsid munged --foreground --force --socket="$WORK/munge/munge.socket" --key-file="$WORK/munge/munge.key" \
  --pid-file="$WORK/munge/munged.pid" --seed-file="$WORK/munge/munged.seed" --log-file="$WORK/log/munged.log" \
  > "$WORK/log/munged.out" 2>&1 &
PIDS+=($!)
for _ in $(seq 50); do [ -S "$WORK/munge/munge.socket" ] && break; sleep 0.2; done

# slurm.conf: this host as the controller and the one node (its CPUs and memory as slurmd sees them)
HOST=$(hostname -s)
NODE=$(slurmd -C | head -n 1 | sed "s/^NodeName=[^ ]*/NodeName=$HOST NodeAddr=127.0.0.1/")
mkdir -p "$(dirname "$CONF")"
cat > "$CONF" << EOF
$MARK (removed when it ends; state and logs in $WORK)
ClusterName=calibtest
SlurmctldHost=$HOST(127.0.0.1)
SlurmUser=root
SlurmdUser=root
SlurmctldPort=16817
SlurmdPort=16818
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$WORK/munge/munge.socket
StateSaveLocation=$WORK/state
SlurmdSpoolDir=$WORK/spool
SlurmctldPidFile=$WORK/slurmctld.pid
SlurmdPidFile=$WORK/slurmd.pid
SlurmctldLogFile=$WORK/log/slurmctld.log
SlurmdLogFile=$WORK/log/slurmd.log
MailProg=/bin/true
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MpiDefault=none
$NODE State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
setsid slurmctld -D -f "$CONF" > "$WORK/log/slurmctld.out" 2>&1 &
PIDS+=($!)
setsid slurmd -D -f "$CONF" > "$WORK/log/slurmd.out" 2>&1 &
PIDS+=($!)
for _ in $(seq 60); do [ "$(sinfo -h -N -o %T 2> /dev/null)" = idle ] && break; sleep 0.5; done
sinfo -N -o "%N %P %T %c %m" | sed 's/^/  /'
[ "$(sinfo -h -N -o %T)" = idle ] || { echo "the node did not come up"; exit 1; }
echo "cluster up after $((SECONDS - T0)) s"

# the .test study: through SLURM, then locally, both into $RES and moved aside (see the header)
RES="$WORK/results"
# as the .test chain of run.py: a figure with an empty panel fails its rule (CALIB_FIGURE_CHECK=warn: printed only)
export CALIB_FIGURE_CHECK=${CALIB_FIGURE_CHECK:-strict}
echo "+ tools/slurm_run.py --profile workflow/profiles/slurm-small --configfile .test/config.yaml (results: $RES)"
t=$SECONDS
python tools/slurm_run.py --profile workflow/profiles/slurm-small --configfile .test/config.yaml \
  --config "results=$RES" > "$WORK/log/snakemake_slurm.log" 2>&1 \
  || { tail -n 60 "$WORK/log/snakemake_slurm.log"; echo "the SLURM run failed (log: $WORK/log/snakemake_slurm.log)"; exit 1; }
SLURM_S=$((SECONDS - t))
JOBS=$(grep -c "has been submitted with SLURM jobid" "$WORK/log/snakemake_slurm.log" || true)
ACCEPTED=$(grep -c "_slurm_rpc_submit_batch_job: JobId=" "$WORK/log/slurmctld.log" || true)
grep "slurm_run:" "$WORK/log/snakemake_slurm.log" | sed 's/^/  /'
mv "$RES" "$WORK/slurm"

echo "+ snakemake --profile workflow/profiles/default --configfile .test/config.yaml (results: $RES)"
t=$SECONDS
snakemake --profile workflow/profiles/default --configfile .test/config.yaml --config "results=$RES" \
  > "$WORK/log/snakemake_local.log" 2>&1 \
  || { tail -n 60 "$WORK/log/snakemake_local.log"; echo "the local run failed (log: $WORK/log/snakemake_local.log)"; exit 1; }
LOCAL_S=$((SECONDS - t))
mv "$RES" "$WORK/local"

python tools/hash_products.py "$WORK/local" > "$WORK/local.tsv"
python tools/hash_products.py "$WORK/slurm" > "$WORK/slurm.tsv"
python tools/hash_products.py --compare "$WORK/local.tsv" "$WORK/slurm.tsv" > "$WORK/compare.tsv" 2>&1 || true
tail -n +2 "$WORK/compare.tsv" | grep -v $'\tidentical$' | grep -v '^#' | head -n 20 || true
PRODUCTS=$(tail -n +2 "$WORK/compare.tsv" | grep -vc '^#' || true)   # rows: products of either run
DIFF=$(tail -n +2 "$WORK/compare.tsv" | grep -v '^#' | grep -vc $'\tidentical$' || true)
echo "slurm_cluster: SLURM $JOBS jobs (slurmctld accepted $ACCEPTED), wall $SLURM_S s; local wall $LOCAL_S s;" \
  "$PRODUCTS products, $DIFF differing ($(date -u +%F), $(nproc) CPUs)"
[ "$DIFF" -eq 0 ] && [ "$PRODUCTS" -gt 0 ] && [ "$JOBS" -gt 0 ]
