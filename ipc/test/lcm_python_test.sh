#!/usr/bin/env bash
# Python (PyPI lcm) decoding our LCM messages: from a file:// log our C++ publisher
# wrote and, as root, live over udpm inside a private network namespace.
# Skips (77) when the Python lcm module is not installed (optional dependency).
# usage: lcm_python_test.sh PYTHON BIN_DIR GEN_PYTHON_DIR WORK_DIR
set -uo pipefail
py=$1 bin=$2 gen=$3 work=$4
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
"$py" -c "import lcm" 2>/dev/null || { echo "SKIP: $py has no lcm module (pip install lcm)"; exit 77; }
rm -rf "$work" && mkdir -p "$work"
log="$work/py.lcmlog"
"$bin/ipc_probe" pub --transport lcm --url "file://$log?mode=w" --count 400 --rate 20000 --status-every 40 \
  || { echo "FAIL: writing the log"; exit 1; }
"$py" "$here/lcm_python_check.py" "$gen" "file://$log?speed=0" 400 10 || { echo "FAIL: python file:// decode"; exit 1; }
if [[ $(id -u) -ne 0 ]] || ! command -v ip >/dev/null; then
  echo "PASS (file:// only: live udpm part needs root for ip netns)"; exit 0
fi
ns="sp-ipc-py-$$-$RANDOM"
trap 'for p in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$p"; done; wait 2>/dev/null; ip netns del "$ns" 2>/dev/null' EXIT
ip netns add "$ns" || { echo "PASS (file:// only: cannot create a network namespace)"; exit 0; }
ip netns exec "$ns" ip link set lo up && ip netns exec "$ns" ip route add 224.0.0.0/4 dev lo || { echo "FAIL: namespace setup"; exit 1; }
url="udpm://239.255.76.67:7667?ttl=0"
ip netns exec "$ns" "$py" "$here/lcm_python_check.py" "$gen" "$url" 500 10 _PY "$work/ready" >"$work/py.out" 2>&1 &
sub=$!
ip netns exec "$ns" "$bin/ipc_probe" pub --transport lcm --url "$url" --suffix _PY --count 500 --rate 1000 \
  --status-every 50 --ready-file "$work/ready" --timeout 20 || { echo "FAIL: publisher"; exit 1; }
wait $sub; rc=$?
cat "$work/py.out"
[[ $rc -eq 0 ]] || { echo "FAIL: live python subscriber"; exit 1; }
echo "PASS"
