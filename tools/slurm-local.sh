#!/usr/bin/env bash
# A one-node Slurm on this machine, for `needlesim score --slurm` and its test (docs/scoring.md).
#
#   bash tools/slurm-local.sh up      # install what is missing (Debian 12), start slurmctld and
#                                     # slurmd on 127.0.0.1; prints the SLURM_CONF to export
#   bash tools/slurm-local.sh down    # stop both and remove the state folder (always safe)
#   bash tools/slurm-local.sh env     # prints `export SLURM_CONF=...`
#
# Everything lives under $NEEDLESIM_SLURM_DIR (default /tmp/needlesim-slurm): slurm.conf, the
# controller's state, slurmd's spool, the logs and pid files. Nothing is written to /etc: the
# client commands (sbatch, squeue, sinfo) find the configuration through SLURM_CONF.
#
# Authentication: AuthType=auth/none (and CredType=cred/none). Slurm 22.05 (Debian 12) still
# ships the plugin; it trusts whatever user id a request claims, which is acceptable here only
# because both daemons listen on the loopback address of a machine whose users we trust. A real
# cluster uses munge (AuthType=auth/munge, CredType=cred/munge, one /etc/munge/munge.key on every
# node, munged running): docs/scoring.md.
#
# The ports are 16817 (slurmctld) and 16818 (slurmd), not Slurm's 6817/6818, so that it does
# not collide with a Slurm already on the machine. `up` is idempotent: daemons that answer are
# left running.
set -euo pipefail
DIR="${NEEDLESIM_SLURM_DIR:-/tmp/needlesim-slurm}"
CONF="$DIR/slurm.conf"
NODE=nslocal
export SLURM_CONF="$CONF"

install_missing() {
    local missing=()
    for p in slurmctld slurmd slurm-client; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    echo "slurm-local: installing ${missing[*]}" >&2
    local sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
}

write_conf() {
    local cpus mem user
    cpus=$(nproc)
    # RealMemory in MiB, less a margin for the system (slurmd refuses a node that claims more
    # than it has).
    mem=$(awk '/^MemTotal:/ {printf "%d", $2 / 1024 * 0.9}' /proc/meminfo)
    user=$(id -un)
    mkdir -p "$DIR/state" "$DIR/spool"
    cat >"$CONF.part" <<EOF
# written by tools/slurm-local.sh: a one-node Slurm on the loopback address
ClusterName=needlesim-local
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=16817
SlurmdPort=16818
AuthType=auth/none
CredType=cred/none
SlurmUser=$user
SlurmdUser=root
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/slurmctld.log
SlurmdLogFile=$DIR/slurmd.log
ProctrackType=proctrack/pgid
TaskPlugin=task/none
MpiDefault=none
SwitchType=switch/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
MinJobAge=60
KillWait=5
NodeName=$NODE NodeHostname=$(hostname) NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=local Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
    mv "$CONF.part" "$CONF"
}

alive() { # pid file
    [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null
}

up() {
    install_missing
    if alive "$DIR/slurmctld.pid" && alive "$DIR/slurmd.pid" && sinfo -h >/dev/null 2>&1; then
        echo "slurm-local: already up ($CONF)" >&2
    else
        down quiet
        write_conf
        slurmctld -i -f "$CONF"
        slurmd -N "$NODE" -f "$CONF"
    fi
    # Wait until the node takes jobs (idle), at most 60 s.
    local state=""
    for _ in $(seq 1 120); do
        state=$(sinfo -h -N -n "$NODE" -o '%t' 2>/dev/null || true)
        case "$state" in idle* | mix* | alloc*) break ;; esac
        sleep 0.5
    done
    case "$state" in
    idle* | mix* | alloc*) ;;
    *)
        echo "slurm-local: the node did not come up (state '$state'); logs: $DIR/slurmctld.log, $DIR/slurmd.log" >&2
        tail -5 "$DIR/slurmctld.log" "$DIR/slurmd.log" >&2 2>/dev/null || true
        return 1
        ;;
    esac
    echo "slurm-local: up, node $NODE $state" >&2
    echo "export SLURM_CONF=$CONF"
}

down() {
    local quiet="${1:-}"
    # Our own daemons only, by the pids they wrote; then whatever jobs they left.
    for d in slurmd slurmctld; do
        if alive "$DIR/$d.pid"; then
            local pid
            pid=$(cat "$DIR/$d.pid")
            kill "$pid" 2>/dev/null || true
            for _ in $(seq 1 40); do kill -0 "$pid" 2>/dev/null || break; sleep 0.25; done
            kill -9 "$pid" 2>/dev/null || true
        fi
    done
    rm -rf "$DIR"
    [ -n "$quiet" ] || echo "slurm-local: down" >&2
}

case "${1:-}" in
up) up ;;
down) down ;;
env) echo "export SLURM_CONF=$CONF" ;;
*)
    echo "usage: bash tools/slurm-local.sh up|down|env" >&2
    exit 2
    ;;
esac
