#!/usr/bin/env bash
# A one-node Slurm on this machine, to try tools/cluster/tiles-slurm.sh without a cluster
# (Debian or Ubuntu, as root; it installs slurm-wlm and munge and writes /etc/slurm/slurm.conf,
# so run it in a container or a throwaway VM, not on a machine whose Slurm you keep).
#
#   tools/cluster/one-node-slurm.sh        # then, e.g.:
#   TILE_CPUS=1 TILE_MEMORY=2G WAIT=1 tools/cluster/tiles-slurm.sh MAP OUT 4
#
# The node offers every processor and 80 % of the memory; one partition, `debug`.
set -euo pipefail
[ "$(id -u)" = 0 ] || { echo "one-node-slurm.sh: run as root (it installs and starts daemons)" >&2; exit 64; }
command -v slurmctld >/dev/null || { apt-get update -q && apt-get install -y -q slurm-wlm munge; }
host=$(hostname -s)
cpus=$(getconf _NPROCESSORS_ONLN)
memory=$(awk '/MemTotal/ { printf "%d", $2 / 1024 * 0.8 }' /proc/meminfo)
mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm /run/munge
cat > /etc/slurm/slurm.conf <<CONF
ClusterName=local
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
NodeName=$host CPUs=$cpus RealMemory=$memory State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
chown munge:munge /run/munge
pgrep -x munged >/dev/null || su -s /bin/sh munge -c /usr/sbin/munged
pgrep -x slurmctld >/dev/null || slurmctld
pgrep -x slurmd >/dev/null || slurmd
for _ in $(seq 30); do
    sinfo -h -o %T 2>/dev/null | grep -q idle && { sinfo; exit 0; }
    sleep 1
done
echo "one-node-slurm.sh: the node did not come up; see /var/log/slurm/" >&2
exit 1
