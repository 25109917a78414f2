#!/usr/bin/env bash
# A single-node SLURM on this machine, for the `slurm` tests (tests/test_slurm.py) and for trying a study by hand.
#
#   tests/slurm/cluster.sh start        prints the cluster's folder DIR last; then: export SLURM_CONF=DIR/etc/slurm.conf
#   tests/slurm/cluster.sh stop DIR     cancels every job, stops the daemons, waits until none is left
#
# Everything lives in DIR (a new /tmp/arcsem-slurm.XXXXXX): configs, munge key and socket, MariaDB data, state,
# spool, logs and pid files; nothing is written to /etc. Daemons: munged (as the munge user), MariaDB and slurmdbd
# (the accounting `sacct` reads: submitit polls it for job states), slurmctld and slurmd (as root). Ports are
# free ones chosen at start. Needs root and Debian's slurmctld slurmd slurmdbd slurm-client munge mariadb-server
# (`make slurm` installs them). On a failure `start` prints `error: ...` with the log's tail, stops what it
# started and exits with 1.
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"

die() { echo "error: $*" >&2; exit 1; }

free_ports() {  # n free TCP ports on 127.0.0.1
  python3 -c "import socket,sys
s=[socket.socket() for _ in range(int(sys.argv[1]))]
[x.bind(('127.0.0.1',0)) for x in s]; print(' '.join(str(x.getsockname()[1]) for x in s))" "$1"
}

fill() {  # fill TEMPLATE's @FIELDS@ into OUT
  sed -e "s|@DIR@|$DIR|g" -e "s|@HOST@|$HOST|g" -e "s|@CTLD_PORT@|$CTLD_PORT|g" -e "s|@SLURMD_PORT@|$SLURMD_PORT|g" \
      -e "s|@DBD_PORT@|$DBD_PORT|g" -e "s|@DB_PORT@|$DB_PORT|g" -e "s|@NODE@|$NODE|g" "$1" > "$2"
}

wait_for() {  # wait_for SECONDS WHAT COMMAND...: retry COMMAND every 0.2 s
  local t=$(( $1 * 5 )) what=$2; shift 2
  until timeout 5 "$@" >/dev/null 2>&1; do
    t=$(( t - 1 )); [ "$t" -gt 0 ] || die "$what did not come up ($(tail -n 3 "$DIR"/log/* 2>/dev/null | tr '\n' ' '))"
    sleep 0.2
  done
}

start_munge() {
  mkdir -p "$DIR/munge"
  dd if=/dev/urandom of="$DIR/munge/munge.key" bs=1024 count=1 status=none
  chown -R munge: "$DIR/munge" && chmod 755 "$DIR/munge" && chmod 400 "$DIR/munge/munge.key"
  runuser -u munge -- munged --key-file="$DIR/munge/munge.key" --socket="$DIR/munge/munge.socket" \
    --pid-file="$DIR/munge/munged.pid" --log-file="$DIR/munge/munged.log" --seed-file="$DIR/munge/munged.seed"
  ln -sf "$DIR/munge/munged.pid" "$DIR/run/munged.pid"
  wait_for 10 munged sh -c "munge -S '$DIR/munge/munge.socket' -n | unmunge -S '$DIR/munge/munge.socket'"
}

start_mariadb() {
  mariadb-install-db --no-defaults --datadir="$DIR/db" --user=root --auth-root-authentication-method=socket \
    --skip-test-db > "$DIR/log/mariadb-install.log" 2>&1 || die "mariadb-install-db failed ($DIR/log/mariadb-install.log)"
  setsid mariadbd --no-defaults --datadir="$DIR/db" --socket="$DIR/run/mysql.sock" --port="$DB_PORT" \
    --bind-address=127.0.0.1 --user=root --pid-file="$DIR/run/mariadbd.pid" --log-error="$DIR/log/mariadb.log" \
    --innodb-buffer-pool-size=64M --innodb-lock-wait-timeout=900 --skip-log-bin </dev/null >/dev/null 2>&1 &
  wait_for 30 MariaDB mariadb --no-defaults -S "$DIR/run/mysql.sock" -u root -e "select 1"
  mariadb --no-defaults -S "$DIR/run/mysql.sock" -u root -e "create user 'slurm'@'127.0.0.1' identified by 'slurm';
    grant all on slurm_acct_db.* to 'slurm'@'127.0.0.1';"
}

start_slurm() {
  slurmdbd
  wait_for 60 slurmdbd sacctmgr -i list cluster
  sacctmgr -i add cluster arcsem >/dev/null
  slurmctld
  slurmd
  wait_for 60 "the node (sinfo: idle)" sh -c 'sinfo -h -o %T | grep -qx idle'
}

start() {
  [ "$(id -u)" = 0 ] || die "the test cluster's daemons run as root"
  for exe in munged slurmctld slurmd slurmdbd sinfo sacctmgr mariadbd mariadb-install-db runuser python3; do
    command -v "$exe" >/dev/null || die "$exe not found (make slurm)"
  done
  DIR="$(mktemp -d /tmp/arcsem-slurm.XXXXXX)" && chmod 755 "$DIR"
  mkdir -p "$DIR/etc" "$DIR/state" "$DIR/spool" "$DIR/log" "$DIR/run"
  trap 'stop >/dev/null 2>&1 || true' EXIT  # a failed start stops what it started
  HOST="$(hostname -s)"
  read -r CTLD_PORT SLURMD_PORT DBD_PORT DB_PORT < <(free_ports 4)
  NODE="$(slurmd -C | head -n 1)"
  fill "$HERE/slurm.conf" "$DIR/etc/slurm.conf"
  fill "$HERE/slurmdbd.conf" "$DIR/etc/slurmdbd.conf" && chmod 600 "$DIR/etc/slurmdbd.conf"
  export SLURM_CONF="$DIR/etc/slurm.conf"
  start_munge
  start_mariadb
  start_slurm
  trap - EXIT
  echo "$DIR"
}

pid_of() { cat "$DIR/run/$1.pid" 2>/dev/null || true; }

stop_daemons() {  # SIGTERM to each daemon named, wait up to 10 s for all, SIGKILL what is left
  local pids="" pid
  for d in "$@"; do
    pid="$(pid_of "$d")"
    [ -n "$pid" ] && kill "$pid" 2>/dev/null && pids="$pids $pid"
  done
  for _ in $(seq 100); do
    local alive=""
    for pid in $pids; do kill -0 "$pid" 2>/dev/null && alive="$alive $pid"; done
    pids="$alive"; [ -z "$pids" ] && return 0
    sleep 0.1
  done
  kill -9 $pids 2>/dev/null || true
}

stop() {
  [ -f "$DIR/etc/slurm.conf" ] || die "$DIR is not a cluster folder of this script"
  export SLURM_CONF="$DIR/etc/slurm.conf"
  if [ -n "$(pid_of slurmctld)" ]; then  # no job may outlive the cluster (slurmstepd and its tasks)
    scancel --full --quiet --user=root 2>/dev/null || true
    for _ in $(seq 50); do [ -z "$(squeue -h -o %i 2>/dev/null)" ] && break; sleep 0.2; done
  fi
  stop_daemons slurmd slurmctld  # the cluster, then what it needs
  stop_daemons slurmdbd mariadbd munged
  rm -rf "$DIR"
}

case "${1:-}" in
  start) start ;;
  stop) [ -n "${2:-}" ] || die "usage: $0 stop DIR"; DIR="$2"; stop ;;
  *) echo "usage: $0 start | stop DIR" >&2; exit 2 ;;
esac
