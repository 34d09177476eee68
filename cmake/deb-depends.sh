#!/usr/bin/env bash
# Prints the Debian "Depends:" value for the ELF files under a staged install
# tree: every shared library they need, mapped to its package by the host's
# shlibs files (as dpkg-shlibdeps does without symbols files).
#
#   bash cmake/deb-depends.sh STAGING_DIR
#
# Works for cross builds too: library package names (libopencv-core406, ...)
# are the same on every Debian architecture, so the host's amd64 shlibs
# answer for arm64 binaries. dpkg-shlibdeps itself cannot: the arm64 sysroot
# has no dpkg database. Needs the host's -dev packages (.ci/install-deps).
set -euo pipefail

dir=${1:?usage: deb-depends.sh STAGING_DIR}

sonames=$(find "$dir" -type f -print0 |
  while IFS= read -r -d '' f; do
    [[ $(head -c4 "$f" | od -An -c | tr -d ' ') == '177ELF' ]] || continue
    readelf -d "$f" | sed -n 's/.*(NEEDED).*Shared library: \[\(.*\)\]/\1/p'
  done | sort -u)

# shlibs lines "libname soversion dependency", without udeb and without the
# cross-toolchain packages (libc6-arm64-cross & co.).
shlibs=$(find /var/lib/dpkg/info -name '*.shlibs' ! -name '*-cross.shlibs' -exec cat {} + |
         awk '$1 !~ /:$/ && NF >= 3')
multiarch=$(dpkg-architecture -qDEB_HOST_MULTIARCH 2>/dev/null || gcc -print-multiarch)

deps=()
missing=()
for soname in $sonames; do
  if [[ $soname =~ ^(.+)\.so\.([0-9].*)$ ]]; then
    name=${BASH_REMATCH[1]} version=${BASH_REMATCH[2]}
  elif [[ $soname =~ ^(.+)-([0-9][0-9.]*)\.so$ ]]; then
    name=${BASH_REMATCH[1]} version=${BASH_REMATCH[2]}
  else
    name=${soname%.so} version=
  fi
  # Another architecture's dynamic loader (ld-linux-aarch64.so.1) is glibc's.
  [[ $name == ld-linux* ]] && name=libc version=6
  dep=$(awk -v n="$name" -v v="$version" '$1 == n && $2 == v { $1 = ""; $2 = ""; sub(/^ +/, ""); print; exit }' <<<"$shlibs")
  if [[ -z $dep ]]; then
    for d in /usr/lib/$multiarch /lib/$multiarch /usr/lib /lib; do
      if dep=$(dpkg-query -S "$d/$soname" 2>/dev/null); then
        dep=${dep%%:*}
        break
      fi
      dep=
    done
  fi
  if [[ -z $dep ]]; then
    missing+=("$soname")
    continue
  fi
  deps+=("$(sed -E 's/:(amd64|arm64|armhf|i386|any|native)\b//g' <<<"$dep")")  # drop :arch qualifiers
done
if [[ ${#missing[@]} -gt 0 ]]; then
  echo "deb-depends: no package found for: ${missing[*]}" >&2
  exit 1
fi
printf '%s\n' "${deps[@]}" | sort -u | paste -sd, - | sed 's/,/, /g'
