#!/usr/bin/env bash
# System packages the tests use: tmux (teleop in a real terminal), Debian's chromium
# (viewer page tests) and podman (container test). Installs only what is missing, and only
# as root with apt; elsewhere it says what is missing and the tests that need it skip.
# FLEETSIM_NO_SYSTEM=1 changes nothing on the machine: the tests that need what is missing skip.
set -euo pipefail
if [ "${FLEETSIM_NO_SYSTEM:-0}" = 1 ]; then
  echo "setup-system: FLEETSIM_NO_SYSTEM=1: installing nothing (tests that need tmux, chromium or podman skip)"
  exit 0
fi
here="$(cd "$(dirname "$0")/.." && pwd)"
need=()
command -v tmux >/dev/null || need+=(tmux)
command -v chromium >/dev/null || need+=(chromium)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup-system: installing ${need[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null 2>&1 || apt-get install -y -qq --no-install-recommends "${need[@]}"
  else
    echo "setup-system: missing ${need[*]} (not root or no apt): the tests that need them will skip"
  fi
fi
if [ -f "$here/docker/ci-setup.sh" ] && [ "${FLEETSIM_SKIP_CONTAINER:-0}" != 1 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    bash "$here/docker/ci-setup.sh"
  else
    echo "setup-system: not root: skipping the podman setup (the container test will skip)"
  fi
fi
