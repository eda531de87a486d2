#!/usr/bin/env bash
# Bring up the CAN interface the IEM plug-in uses: a virtual one for tests (vcan) or a real
# CAN FD adapter (can) with the wire protocol's bitrates. Needs root (ip link, modprobe).
set -euo pipefail

PROG=$(basename "$0")
DEFAULT_VCAN=vcan0
DEFAULT_BITRATE=1000000   # arbitration phase, bit/s (protocol.dbc: 1 Mbit/s)
DEFAULT_DBITRATE=5000000  # CAN FD data phase, bit/s (protocol.dbc: 5 Mbit/s)
DEFAULT_RESTART_MS=100    # ms after a bus-off until the interface restarts by itself
VCAN_FD_MTU=72            # CANFD_MTU: vcan drops CAN FD frames until its MTU is 72

usage() {
    cat <<EOF
usage: $PROG vcan [NAME]
       $PROG can IFACE [BITRATE DBITRATE]
       $PROG --help

Set up a CAN interface for the IEM plug-in (run as root).

  vcan [NAME]   load the vcan module, add the virtual CAN interface NAME (default
                $DEFAULT_VCAN) unless it exists, make it CAN FD capable (mtu
                $VCAN_FD_MTU: vcan drops FD frames otherwise) and bring it up. For tests
                on a Linux host: link kind "socketcan", channel NAME.
  can IFACE [BITRATE DBITRATE]
                configure a CAN FD adapter (e.g. can0, candleLight/gs_usb) and bring it
                up: ip link set IFACE type can bitrate BITRATE dbitrate DBITRATE fd on
                restart-ms $DEFAULT_RESTART_MS (after bus-off the interface restarts by
                itself instead of staying off).
                Defaults: bitrate $DEFAULT_BITRATE, dbitrate $DEFAULT_DBITRATE (the fd
                profile). The classic profile needs the same 1 Mbit/s arbitration rate;
                an FD-capable adapter carries it with fd on.

Examples:
  sudo $PROG vcan
  sudo $PROG can can0
  sudo $PROG can can0 1000000 5000000
EOF
}

die() {
    echo "$PROG: error: $*" >&2
    exit 2
}

need_root() {
    [[ $(id -u) -eq 0 ]] || die "must run as root (ip link and modprobe change the system); try: sudo $PROG $*"
}

is_positive_int() {
    [[ $1 =~ ^[1-9][0-9]*$ ]]
}

setup_vcan() {
    local name=${1:-$DEFAULT_VCAN}
    need_root vcan "$name"
    command -v ip >/dev/null || die "'ip' not found (install iproute2)"
    if ! modprobe vcan; then
        die "cannot load the vcan kernel module (is this kernel built with CONFIG_CAN_VCAN?)"
    fi
    if ip link show dev "$name" >/dev/null 2>&1; then
        echo "$PROG: $name exists; not adding it again"
    else
        ip link add dev "$name" type vcan || die "cannot add the vcan interface $name"
    fi
    ip link set "$name" down || die "cannot take $name down"
    ip link set "$name" mtu "$VCAN_FD_MTU" \
        || die "cannot set $name's MTU to $VCAN_FD_MTU (CAN FD); is it a vcan interface?"
    ip link set "$name" up || die "cannot bring $name up"
    echo "$PROG: $name is up (virtual CAN, CAN FD capable: mtu $VCAN_FD_MTU)"
}

setup_can() {
    [[ $# -ge 1 ]] || die "'can' needs an interface name, e.g. '$PROG can can0' (see --help)"
    [[ $# -eq 1 || $# -eq 3 ]] || die "'can' takes IFACE and optionally both BITRATE and DBITRATE; got $# arguments (see --help)"
    local iface=$1
    local bitrate=${2:-$DEFAULT_BITRATE}
    local dbitrate=${3:-$DEFAULT_DBITRATE}
    is_positive_int "$bitrate" || die "BITRATE must be a positive integer in bit/s, e.g. $DEFAULT_BITRATE; got '$bitrate'"
    is_positive_int "$dbitrate" || die "DBITRATE must be a positive integer in bit/s, e.g. $DEFAULT_DBITRATE; got '$dbitrate'"
    need_root can "$@"
    command -v ip >/dev/null || die "'ip' not found (install iproute2)"
    ip link show dev "$iface" >/dev/null 2>&1 \
        || die "no interface '$iface' (is the adapter plugged in? 'ip -details link show' lists them)"
    ip link set "$iface" down || die "cannot take $iface down"
    ip link set "$iface" type can bitrate "$bitrate" dbitrate "$dbitrate" fd on \
        restart-ms "$DEFAULT_RESTART_MS" \
        || die "cannot set $iface to bitrate $bitrate, dbitrate $dbitrate, fd on, restart-ms $DEFAULT_RESTART_MS (does the adapter support CAN FD and these rates?)"
    ip link set "$iface" up || die "cannot bring $iface up"
    echo "$PROG: $iface is up: bitrate $bitrate, dbitrate $dbitrate, CAN FD on, restart-ms $DEFAULT_RESTART_MS"
}

main() {
    [[ $# -ge 1 ]] || { usage >&2; exit 2; }
    local cmd=$1
    shift
    case $cmd in
        -h|--help|help) usage ;;
        vcan)
            [[ $# -le 1 ]] || die "'vcan' takes at most one NAME; got $# arguments (see --help)"
            setup_vcan "$@"
            ;;
        can) setup_can "$@" ;;
        *) die "unknown command '$cmd'; valid are: vcan, can, --help" ;;
    esac
}

main "$@"
