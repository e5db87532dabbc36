#!/usr/bin/env bash
# Prepare a Debian bookworm machine (CI runs this as root) to build and run the fleetsim
# image with podman, with no container registry:
#   1. apt-install podman runc iptables mmdebstrap (only those that are missing);
#   2. write /etc/containers/containers.conf (runc, ulimits that fit a machine without
#      CAP_SYS_RESOURCE, the host CA bundle for TLS-re-signing networks) unless it already
#      selects runc; an existing file is backed up first;
#   3. build the local base image localhost/bookworm-py:base (Debian python3 + python3-venv)
#      with mmdebstrap, caching the rootfs tar under /var/tmp.
# Idempotent: a second run does nothing but checks (about a second). Exits non-zero only
# when a step really fails. See docs/container.md.
#
# Environment overrides:
#   FLEETSIM_BASE_IMAGE   (default localhost/bookworm-py:base)
#   FLEETSIM_ROOTFS_TAR   (default /var/tmp/bookworm-py.tar)
#   DEBIAN_MIRROR         (default http://deb.debian.org/debian)
#   DEBIAN_SUITE          (default bookworm)
set -euo pipefail

BASE_IMAGE=${FLEETSIM_BASE_IMAGE:-localhost/bookworm-py:base}
ROOTFS=${FLEETSIM_ROOTFS_TAR:-/var/tmp/bookworm-py.tar}
MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
SUITE=${DEBIAN_SUITE:-bookworm}
CONF=/etc/containers/containers.conf
CA_BUNDLE=/etc/ssl/certs/ca-certificates.crt

now() { date +%s.%N; }
T0=$(now)
STEP_T=$T0
say() { printf 'ci-setup: %s\n' "$*"; }
die() { printf 'ci-setup: error: %s\n' "$*" >&2; exit 1; }
step_done() {  # awk is Essential in Debian, bc is not
    local t
    t=$(now)
    say "$(awk -v a="$STEP_T" -v b="$t" -v n="$1" 'BEGIN { printf "%-36s %6.1f s", n, b - a }')"
    STEP_T=$t
}

SUDO=
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        SUDO=sudo
    fi
fi
as_root() {
    if [ "$(id -u)" -eq 0 ]; then "$@"
    elif [ -n "$SUDO" ]; then $SUDO "$@"
    else die "need root for: $*"
    fi
}

# One setup at a time (two CI jobs on one machine would otherwise race on apt and podman).
LOCK=/var/tmp/fleetsim-ci-setup.lock
if command -v flock >/dev/null 2>&1 && { [ -w /var/tmp ] || [ -w "$LOCK" ]; }; then
    exec 9>"$LOCK"
    flock 9
fi

# -- 1. packages ------------------------------------------------------------------------
installed() { [ "$(dpkg-query -W -f='${Status}' "$1" 2>/dev/null)" = "install ok installed" ]; }
missing=()
for pkg in podman runc iptables mmdebstrap; do
    installed "$pkg" || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
    command -v apt-get >/dev/null 2>&1 || die "missing ${missing[*]} and no apt-get to install them"
    say "installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    as_root apt-get update -qq
    # --no-install-recommends keeps crun out (it cannot run on hybrid cgroups); runc is used
    as_root apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    step_done "apt-get install ${#missing[@]} package(s)"
else
    step_done "packages present"
fi

# -- 2. containers.conf -----------------------------------------------------------------
if [ -f "$CONF" ] && grep -Eq '^[[:space:]]*runtime[[:space:]]*=[[:space:]]*"runc"' "$CONF"; then
    step_done "containers.conf already uses runc"
else
    if [ -f "$CONF" ]; then
        backup="$CONF.bak.$(date +%Y%m%d%H%M%S)"
        as_root cp -p "$CONF" "$backup"
        say "backed up $CONF to $backup"
    fi
    volumes=""
    if [ -s "$CA_BUNDLE" ]; then
        # networks that re-sign TLS: RUN steps (pip) need the host's CA bundle; read-only,
        # never baked into an image
        volumes="volumes = [\"$CA_BUNDLE:$CA_BUNDLE:ro\"]"
    fi
    as_root mkdir -p /etc/containers
    as_root tee "$CONF" >/dev/null <<CONF
# written by fleetsim docker/ci-setup.sh
[containers]
# no CAP_SYS_RESOURCE on some CI VMs: keep nofile <= 20000 and nproc <= 32768
default_ulimits = ["nofile=16384:16384", "nproc=16384:16384"]
$volumes

[engine]
# crun refuses hybrid (v1 + v2) cgroup hierarchies
runtime = "runc"
CONF
    step_done "wrote $CONF"
fi

podman info >/dev/null 2>&1 || { podman info >&2 || true; die "podman info fails"; }
step_done "podman info"

# -- 3. base image ----------------------------------------------------------------------
if podman image exists "$BASE_IMAGE"; then
    step_done "base image $BASE_IMAGE present"
else
    if [ ! -s "$ROOTFS" ]; then
        say "building $SUITE rootfs with mmdebstrap into $ROOTFS (about 45 s)"
        tmp="$ROOTFS.tmp.$$"
        trap 'rm -f "$tmp"' EXIT
        as_root mmdebstrap --quiet --variant=minbase --include=python3-venv,ca-certificates \
            --aptopt='APT::Install-Recommends "false"' \
            --dpkgopt='path-exclude=/usr/share/man/*' --dpkgopt='path-exclude=/usr/share/doc/*' \
            --dpkgopt='path-include=/usr/share/doc/*/copyright' \
            --dpkgopt='path-exclude=/usr/share/locale/*' \
            --format=tar "$SUITE" "$tmp" "$MIRROR"
        as_root mv -f "$tmp" "$ROOTFS"
        trap - EXIT
        step_done "mmdebstrap rootfs"
    else
        say "reusing cached rootfs $ROOTFS"
    fi
    podman import --quiet --change 'CMD ["/bin/bash"]' "$ROOTFS" "$BASE_IMAGE" >/dev/null
    step_done "podman import $BASE_IMAGE"
fi

podman run --rm --network=host "$BASE_IMAGE" python3 -c 'import venv, ensurepip' \
    || die "$BASE_IMAGE cannot run python3 with venv (delete it and $ROOTFS, then rerun)"
step_done "base image runs python3"

say "$(awk -v a="$T0" -v b="$(now)" 'BEGIN { printf "ready in %.1f s", b - a }')"
