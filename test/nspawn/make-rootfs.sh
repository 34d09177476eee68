#!/usr/bin/env bash
# Cached Debian bookworm minbase root for test/nspawn/stillpointd_nspawn_test.sh:
# systemd, dbus, libnss-systemd (names the DynamicUser) and the packages a
# stillpoint .deb depends on, so the .deb installs with dpkg -i and no network.
# Prints the path of the root tarball. Rebuilt only when the package list or
# this script changes; one build at a time (flock).
#
#   bash test/nspawn/make-rootfs.sh CACHE_DIR PACKAGE.deb
#
# Exit status: 0 ok, 77 the Debian mirror is unreachable (the caller skips),
# 1 anything else.
set -euo pipefail
cache=${1:?usage: make-rootfs.sh CACHE_DIR PACKAGE.deb} deb=${2:?usage: make-rootfs.sh CACHE_DIR PACKAGE.deb}
suite=bookworm

# Depends of the .deb, one name per alternative group (the first), no versions.
depends=$(dpkg-deb -f "$deb" Depends | tr ',' '\n' | sed 's/|.*//; s/(.*)//' | tr -d ' ' | sed '/^$/d')
packages=(systemd dbus libnss-systemd $depends)
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
key=$( { printf '%s\n' "${packages[@]}" | sort -u; sha256sum "$here/make-rootfs.sh" | cut -d' ' -f1; } |
       sha256sum | cut -c1-16)
tarball=$cache/rootfs-$suite-$key.tar

mkdir -p "$cache"
exec 9>"$cache/.lock"
flock 9
if [[ -s $tarball ]]; then
  echo "$tarball"
  exit 0
fi

# The mirrors apt uses on this host (bookworm, -updates, -security), else deb.debian.org.
mirrors=()
while read -r uri dist; do
  mirrors+=("deb $uri ${dist%%/*} ${dist#*/}")
done < <(LC_ALL=C apt-cache policy 2>/dev/null |
           awk -v s="$suite" '$2 ~ /^https?:/ && $3 ~ "^" s "(-updates|-security)?/main$" {print $2, $3}' | sort -u)
if [[ ${#mirrors[@]} -eq 0 ]]; then
  mirrors=("deb http://deb.debian.org/debian $suite main"
           "deb http://deb.debian.org/debian $suite-updates main"
           "deb http://deb.debian.org/debian-security $suite-security main")
fi

# Reachability of every mirror host (port 80/443) before a long mmdebstrap.
for m in "${mirrors[@]}"; do
  uri=$(awk '{print $2}' <<<"$m")
  host=${uri#*://} host=${host%%/*}
  port=80
  [[ $uri == https:* ]] && port=443
  [[ -n ${http_proxy:-} ]] && continue  # behind a proxy: let apt find out
  if ! timeout 10 bash -c "exec 3<>/dev/tcp/${host%%:*}/$port" 2>/dev/null; then
    echo "make-rootfs: Debian mirror $host:$port unreachable (no network?)" >&2
    exit 77
  fi
done

echo "make-rootfs: building $tarball (${#packages[@]} packages; mirrors: ${mirrors[*]})" >&2
start=$SECONDS
include=$(IFS=,; echo "${packages[*]}")
rm -f "$tarball.tmp"
# Docs and man pages are not needed to boot; apt lists are dropped by mmdebstrap.
mmdebstrap --quiet --variant=minbase --include="$include" \
  --dpkgopt='path-exclude=/usr/share/man/*' --dpkgopt='path-exclude=/usr/share/doc/*' \
  --dpkgopt='path-exclude=/usr/share/locale/*' \
  --format=tar "$suite" "$tarball.tmp" "${mirrors[@]}" </dev/null >&2
mv "$tarball.tmp" "$tarball"
find "$cache" -maxdepth 1 -name "rootfs-$suite-*.tar" ! -path "$tarball" -delete  # older package lists
echo "make-rootfs: built in $((SECONDS - start)) s ($(du -h "$tarball" | cut -f1))" >&2
echo "$tarball"
