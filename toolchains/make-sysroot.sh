#!/usr/bin/env bash
# Builds (or reuses) the Debian bookworm arm64 sysroot that
# toolchains/aarch64-linux-gnu.cmake compiles and links against, and that
# qemu-aarch64-static runs the tests in.
#
#   bash toolchains/make-sysroot.sh            # -> $STILLPOINT_SYSROOT
#   STILLPOINT_SYSROOT=/some/dir bash toolchains/make-sysroot.sh
#
# Default location: /opt/stillpoint-sysroot-arm64 (outside the repository:
# about 1.2 GB). Needs root (mmdebstrap), network access to the Debian mirror
# apt is configured with, and the host packages mmdebstrap, qemu-user-static,
# g++-aarch64-linux-gnu. Idempotent: the sysroot is rebuilt only when the
# package list or this script changed (stamp file .stillpoint-sysroot).
#
# Why not multiarch (apt-get install libceres-dev:arm64 on the host): the
# arm64 ceres/lcm/opencv -dev packages conflict with the amd64 ones.
set -euo pipefail

sysroot=${STILLPOINT_SYSROOT:-/opt/stillpoint-sysroot-arm64}
[[ $sysroot == /* && $sysroot != / ]] || { echo "make-sysroot: need an absolute path other than /: '$sysroot'" >&2; exit 2; }
triplet=aarch64-linux-gnu
suite=bookworm

# Every arm64 -dev package the project (and its tests and benchmarks) links
# against; keep in step with .ci/install-deps. apt resolves the dependencies.
packages=(
  libeigen3-dev
  libopencv-dev       # all modules, dnn included (semantic segmentation)
  libceres-dev        # pulls libatlas-base-dev, glog, gflags, SuiteSparse
  libyaml-cpp-dev
  libgtest-dev
  libgmock-dev
  libbenchmark-dev
  liblcm-dev          # ipc/: LCM pose publishing (lcm-gen runs from the host)
  libglib2.0-dev      # lcm.pc requires glib-2.0
  cyclonedds-dev      # ipc/: DDS pose publishing (idlc runs from the host)
  libsystemd-dev      # stillpointd: sd_notify (libsystemd.pc)
)

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
stamp_text="$(printf '%s\n' "${packages[@]}" | sort) $(sha256sum "$here/make-sysroot.sh" | cut -d' ' -f1)"
stamp_hash=$(printf '%s' "$stamp_text" | sha256sum | cut -d' ' -f1)
stamp_file="$sysroot/.stillpoint-sysroot"

if [[ -f $stamp_file && $(cat "$stamp_file") == "$stamp_hash" ]]; then
  echo "make-sysroot: $sysroot is up to date"
  exit 0
fi

# The Debian mirrors apt uses on this host (bookworm, -updates, -security),
# read from apt's own view of its sources so both sources.list formats work.
mirrors=()
while read -r uri dist; do
  mirrors+=("deb $uri ${dist%%/*} ${dist#*/}")
done < <(LC_ALL=C apt-cache policy 2>/dev/null |
           awk -v s="$suite" '$2 ~ /^(https?|file):/ && $3 ~ "^" s "(-updates|-security)?/main$" {print $2, $3}' |
           sort -u)
if [[ ${#mirrors[@]} -eq 0 ]]; then
  mirrors=("deb http://deb.debian.org/debian $suite main"
           "deb http://deb.debian.org/debian $suite-updates main"
           "deb http://deb.debian.org/debian-security $suite-security main")
fi
printf 'make-sysroot: mirror: %s\n' "${mirrors[@]}"

tmp="$sysroot.tmp"
rm -rf "$tmp"
start=$SECONDS
include=$(IFS=,; echo "${packages[*]}")
# extract: unpack the packages and their dependencies, run no maintainer
# script (nothing arm64 executes here).
mmdebstrap --quiet --variant=extract --architectures=arm64 --include="$include" \
  "$suite" "$tmp" "${mirrors[@]}" </dev/null

# Absolute symlinks point at the host's files once the sysroot is not /:
# rewrite them relative to the sysroot.
find "$tmp" -type l -lname '/*' -print0 |
  while IFS= read -r -d '' link; do
    target=$(readlink "$link")
    ln -sfn "$(realpath -s -m --relative-to="$(dirname "$link")" "$tmp$target")" "$link"
  done

# update-alternatives never ran: give the BLAS/LAPACK names their ATLAS (or
# reference) implementation, as postinst would.
libdir="$tmp/usr/lib/$triplet"
for name in libblas.so libblas.so.3 liblapack.so liblapack.so.3; do
  [[ -e $libdir/$name ]] && continue
  for impl in atlas blas lapack openblas-pthread; do
    if [[ -e $libdir/$impl/$name ]]; then
      ln -sfn "$impl/$name" "$libdir/$name"
      break
    fi
  done
  [[ -e $libdir/$name ]] || { echo "make-sysroot: no implementation of $name" >&2; exit 1; }
done
for pc in blas lapack; do
  [[ -e $libdir/pkgconfig/$pc.pc ]] && continue
  for impl in atlas blas lapack; do
    if [[ -e $libdir/$impl/$pc.pc ]]; then ln -sfn "../$impl/$pc.pc" "$libdir/pkgconfig/$pc.pc"; break; fi
    if [[ -e $libdir/pkgconfig/$pc-$impl.pc ]]; then ln -sfn "$pc-$impl.pc" "$libdir/pkgconfig/$pc.pc"; break; fi
  done
done

echo "$stamp_hash" >"$tmp/.stillpoint-sysroot"
rm -rf "$sysroot"
mv "$tmp" "$sysroot"
echo "make-sysroot: $sysroot ready in $((SECONDS - start)) s ($(du -sh "$sysroot" | cut -f1))"
