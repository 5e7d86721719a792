#!/usr/bin/env bash
# abyss-base:bookworm: Debian 12 with Python 3.11 and venv, made from Debian's own packages with
# debootstrap, for the Dockerfile's `ARG BASE` where no container registry can be reached:
#   bash deploy/base-image.sh [TAG]      # as root, with debootstrap and a running Docker engine
#   docker build --build-arg BASE=abyss-base:bookworm -t abyss:latest .
# The mirrors are the ones apt uses here (MIRROR, SECURITY_MIRROR override them).
set -euo pipefail
TAG="${1:-abyss-base:bookworm}"
SUITE=bookworm
# the first archive named ARCHIVE (debian, debian-security) in apt's sources, one-line or deb822
apt_mirror() {
  cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources 2>/dev/null \
    | grep -E '^[[:space:]]*(deb|URIs:)[[:space:]]' | grep -oE 'https?://[^[:space:]]+' \
    | grep -E "/$1/?\$" | head -n 1 | sed 's:/$::'
}
MIRROR="${MIRROR:-$(apt_mirror debian || true)}"
MIRROR="${MIRROR:-http://deb.debian.org/debian}"
SECURITY_MIRROR="${SECURITY_MIRROR:-$(apt_mirror debian-security || true)}"
SECURITY_MIRROR="${SECURITY_MIRROR:-http://deb.debian.org/debian-security}"

root="$(mktemp -d /tmp/abyss-base.XXXXXX)"
trap 'rm -rf "$root" "$root.log"' EXIT
echo "base-image: debootstrap $SUITE from $MIRROR"
debootstrap --variant=minbase --include=python3,python3-venv,ca-certificates "$SUITE" "$root" "$MIRROR" \
  >"$root.log" 2>&1 || { tail -n 30 "$root.log" >&2; exit 1; }
# the image's apt takes updates and security fixes too, as the official images' does
cat >"$root/etc/apt/sources.list" <<SOURCES
deb $MIRROR $SUITE main
deb $MIRROR $SUITE-updates main
deb $SECURITY_MIRROR $SUITE-security main
SOURCES
rm -rf "$root"/var/cache/apt/archives/*.deb "$root"/var/lib/apt/lists/*
tar -C "$root" -c . | docker import \
  --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
  --change 'ENV LANG=C.UTF-8' --change 'CMD ["/bin/bash"]' \
  --message "debootstrap --variant=minbase $SUITE from $MIRROR" - "$TAG" >/dev/null
echo "base-image: $TAG"
