#!/usr/bin/env bash
# down.sh - stop the one-node SLURM cluster that up.sh started: slurmd, slurmctld
# and munged, each through its pid file. Root only; idempotent (stopping daemons
# that do not run is not an error). Configuration, state and logs are kept.
set -euo pipefail

say() { echo "slurm-down: $*"; }
[[ $(id -u) == 0 ]] || { echo "slurm-down: ERROR: run as root" >&2; exit 1; }

alive() { [[ $(ps -o stat= -p "$1" 2>/dev/null) =~ ^[^Z] ]]; }  # zombies count as gone
stop() {  # name pidfile
    local pid
    pid=$(cat "$2" 2>/dev/null || true)
    if [[ -z $pid ]] || ! alive "$pid"; then
        say "$1 is not running"; rm -f "$2"; return
    fi
    say "stopping $1 (pid $pid)"
    kill "$pid"
    for _ in $(seq 50); do alive "$pid" || { rm -f "$2"; return; }; sleep 0.2; done
    say "$1 did not stop in 10 s: killing it"
    kill -9 "$pid" 2>/dev/null || true
    rm -f "$2"
}

stop slurmd /run/slurm/slurmd.pid
stop slurmctld /run/slurm/slurmctld.pid
stop munged /run/munge/munged.pid
