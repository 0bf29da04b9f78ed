#!/usr/bin/env bash
# up.sh - bring up a one-node SLURM cluster on this machine (localhost), so that
# CI or a laptop can run `sbatch` job arrays and small MPI jobs.
#
#   sudo workflows/slurm/up.sh [--force]      (stop it again with down.sh)
#
# Root only. Idempotent: it installs Debian's slurm-wlm and munge only if they are
# missing, writes /etc/slurm/slurm.conf, starts munged, slurmctld and slurmd by hand
# (it does not need systemd) unless they already run, and waits until the node is
# idle. Running it again on a running cluster changes nothing; if the generated
# slurm.conf differs from the installed one, the daemons are restarted.
# It refuses to overwrite a slurm.conf it did not write, unless --force.
#
# Choices, for a throwaway single-node test cluster:
#  - The node claims EXABRICKS_SLURM_CPUS CPUs (default 4), more than a small CI
#    machine has, so that a 3-rank MPI job fits (SlurmdParameters=config_overrides).
#  - ProctrackType=proctrack/linuxproc and TaskPlugin=task/none: no cgroups needed,
#    so it also works in containers.
#  - No accounting (no slurmdbd, so no sacct); EnforcePartLimits=ALL so that jobs
#    that can never run are rejected at submit time instead of pending forever.
#  - The daemons run as root; logs go to /var/log/slurm/.
set -euo pipefail

MARKER="# Written by exabricks workflows/slurm/up.sh"
CONF=/etc/slurm/slurm.conf
LOGDIR=/var/log/slurm
CPUS=${EXABRICKS_SLURM_CPUS:-4}
TIMEOUT=${EXABRICKS_SLURM_TIMEOUT:-60}

say() { echo "slurm-up: $*"; }
die() { echo "slurm-up: ERROR: $*" >&2; exit 1; }
fail() {  # die, showing the daemons' logs
    for f in /var/log/munge/munged.log "$LOGDIR/slurmctld.log" "$LOGDIR/slurmd.log"; do
        [[ -f $f ]] && { echo "--- tail of $f" >&2; tail -n 15 "$f" >&2; }
    done
    die "$@"
}
running() { grep -q '^ *[^Z ]' <<<"$(ps -C "$1" -o stat= || true)"; }  # zombies do not count

FORCE=0
case ${1:-} in
    --force) FORCE=1 ;;
    "") ;;
    *) die "usage: $0 [--force]" ;;
esac

[[ $(id -u) == 0 ]] || die "run as root"
[[ $CPUS =~ ^[1-9][0-9]*$ ]] || die "EXABRICKS_SLURM_CPUS must be a positive integer, not '$CPUS'"

# 1. Packages.
export PATH=$PATH:/usr/sbin:/sbin
if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null || ! command -v munged >/dev/null; then
    say "installing slurm-wlm and munge"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
fi

# 2. slurm.conf.
HOST=$(hostname -s)
if ! getent hosts "$HOST" >/dev/null; then  # slurmctld must resolve its own node name
    say "hostname '$HOST' does not resolve: adding '127.0.0.1 $HOST' to /etc/hosts"
    echo "127.0.0.1 $HOST  # added by exabricks workflows/slurm/up.sh" >> /etc/hosts
fi
MEM_MB=$(awk '/^MemTotal:/ {print int($2 / 1024)}' /proc/meminfo)
MPI=none
for f in /usr/lib/*/slurm-wlm/mpi_pmi2.so /usr/lib*/slurm/mpi_pmi2.so; do [[ -e $f ]] && MPI=pmi2; done
NEW_CONF="$MARKER; edits are overwritten.
ClusterName=exabricks
SlurmctldHost=$HOST
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=/run/slurm/slurmctld.pid
SlurmdPidFile=/run/slurm/slurmd.pid
SlurmctldLogFile=$LOGDIR/slurmctld.log
SlurmdLogFile=$LOGDIR/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
EnforcePartLimits=ALL
MpiDefault=$MPI
ReturnToService=2
SlurmdParameters=config_overrides
NodeName=$HOST CPUs=$CPUS RealMemory=$MEM_MB State=UNKNOWN
PartitionName=debug Nodes=$HOST Default=YES MaxTime=INFINITE State=UP"

mkdir -p /etc/slurm "$LOGDIR" /run/slurm /var/spool/slurmctld /var/spool/slurmd
if [[ -f $CONF ]] && ! grep -qF "$MARKER" "$CONF" && [[ $FORCE == 0 ]]; then
    die "$CONF was not written by this script; rerun with --force to replace it"
fi
if [[ ! -f $CONF ]] || [[ $(cat "$CONF") != "$NEW_CONF" ]]; then
    if running slurmctld || running slurmd; then
        say "slurm.conf changed: stopping the running daemons"
        "$(dirname "$0")/down.sh"
    fi
    say "writing $CONF (node $HOST, $CPUS CPUs, ${MEM_MB} MB, MpiDefault=$MPI)"
    printf '%s\n' "$NEW_CONF" >"$CONF"
fi

# 3. munge.
if [[ ! -s /etc/munge/munge.key ]]; then
    say "creating /etc/munge/munge.key"
    if command -v mungekey >/dev/null; then mungekey --create --keyfile=/etc/munge/munge.key
    else create-munge-key -f; fi
fi
chown munge:munge /etc/munge/munge.key && chmod 0400 /etc/munge/munge.key
install -d -o munge -g munge -m 0755 /run/munge
if ! running munged; then
    say "starting munged"
    runuser -u munge -- munged || fail "munged did not start"
fi
munge -n | unmunge >/dev/null || fail "munge does not work"

# 4. slurm daemons.
if ! running slurmctld; then
    say "starting slurmctld"
    slurmctld || fail "slurmctld did not start"
fi
for _ in $(seq "$TIMEOUT"); do scontrol ping 2>/dev/null | grep -q UP && break; sleep 1; done
scontrol ping | grep -q UP || fail "slurmctld does not answer"
if ! running slurmd; then
    say "starting slurmd"
    slurmd || fail "slurmd did not start"
fi

# 5. Wait until the node is in service (idle, or busy with jobs).
say "waiting for node $HOST"
resumed=0
for _ in $(seq "$TIMEOUT"); do
    state=$(sinfo -h -n "$HOST" -o %t 2>/dev/null || true)
    case $state in
        idle | mix | alloc) say "cluster up: node $HOST is $state"; exit 0 ;;
        down | drain | drng)
            if [[ $resumed == 0 ]]; then
                say "node is $state: resuming it"
                scontrol update nodename="$HOST" state=resume || true
                resumed=1
            fi ;;
    esac
    sleep 1
done
scontrol show node "$HOST" 2>/dev/null | grep -iE 'state=|reason=' >&2 || true
fail "node $HOST did not become idle within ${TIMEOUT}s (state: '${state:-?}')"
