#!/bin/sh
# Native SocketCAN vcan set-up for ordinary Linux hosts (the vcan-marked tests then run directly).
# Idempotent: an existing, up vcan0 is left alone. Needs root (or CAP_NET_ADMIN + module loading).
#
#   sudo deploy/vcan-setup.sh            # creates and raises vcan0
#   sudo deploy/vcan-setup.sh vcan1      # another name
#
# Kernels without CAN (WSL2's default kernel, many containers, the project's CI machines) cannot
# do this: use the QEMU guest lane instead (docs/vcan.md, python -m tools.vcan_guest).
set -eu

dev="${1:-vcan0}"

die() {
  echo "vcan-setup: $*" >&2
  exit 1
}

command -v ip >/dev/null 2>&1 || die "'ip' not found: install iproute2 (apt-get install iproute2)"

if [ -d "/sys/class/net/$dev" ]; then
  kind="$(ip -details link show dev "$dev" 2>/dev/null | sed -n 's/^ *vcan .*/vcan/p' | head -n 1)"
  [ "$kind" = "vcan" ] || die "$dev exists but is not a vcan device; pick another name"
else
  if [ ! -d /sys/module/vcan ]; then
    if ! modprobe vcan 2>/dev/null; then
      [ "$(id -u)" -eq 0 ] || die "modprobe vcan failed: run as root (sudo $0 $*)"
      die "modprobe vcan failed: this kernel has no vcan module (WSL2? container?). \
Use the QEMU guest lane instead: python -m tools.vcan_guest run -- python -m pytest -m vcan \
(see docs/vcan.md)"
    fi
  fi
  ip link add dev "$dev" type vcan 2>/dev/null \
    || die "ip link add dev $dev type vcan failed (root needed? kernel without CAN?)"
fi

ip link set up "$dev" || die "ip link set up $dev failed"
echo "vcan-setup: $dev is up"
ip -brief link show dev "$dev"
