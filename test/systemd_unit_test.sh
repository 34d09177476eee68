#!/usr/bin/env bash
# systemd/stillpointd.service must pass `systemd-analyze verify` with no output
# at all (verify exits 0 on many bad values and only prints them). The unit is
# checked as shipped, with ExecStart pointed at the built binary (verify needs
# it to exist). A deliberately broken copy must produce output, so the check
# can fail. Prints the `systemd-analyze security` exposure score.
# usage: systemd_unit_test.sh UNIT STILLPOINTD WORKDIR
set -euo pipefail
unit=$1 binary=$2 work=$3
command -v systemd-analyze >/dev/null || { echo "systemd-analyze missing: apt-get install systemd (.ci/install-deps)" >&2; exit 1; }
rm -rf "$work" && mkdir -p "$work"
sed "s#^ExecStart=/usr/bin/stillpointd #ExecStart=$binary #" "$unit" > "$work/stillpointd.service"
grep -q "^ExecStart=$binary " "$work/stillpointd.service" || { echo "ExecStart=/usr/bin/stillpointd not found in $unit" >&2; exit 1; }
cd "$work"
out=$(systemd-analyze verify ./stillpointd.service 2>&1) || { echo "verify failed:"; echo "$out"; exit 1; }
if [[ -n $out ]]; then echo "systemd-analyze verify printed (must print nothing):"; echo "$out"; exit 1; fi
echo "systemd-analyze verify: clean"

# Negative control: a bad value is reported (and would fail the check above).
sed 's/^WatchdogSec=.*/WatchdogSec=soon/' stillpointd.service > broken.service
bad=$(systemd-analyze verify ./broken.service 2>&1 || true)
[[ -n $bad ]] || { echo "negative control: verify printed nothing for WatchdogSec=soon" >&2; exit 1; }

for key in Wants=network-online.target After=network-online.target Type=notify WatchdogSec= Restart=on-failure DynamicUser=yes "AmbientCapabilities=CAP_SYS_NICE CAP_IPC_LOCK" CPUAffinity=; do
  grep -q "^$key" stillpointd.service || { echo "unit lacks $key" >&2; exit 1; }
done
systemd-analyze security --offline=true ./stillpointd.service 2>&1 | grep "Overall exposure level" || true
