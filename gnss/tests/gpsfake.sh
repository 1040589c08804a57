#!/usr/bin/env bash
# gpsd under gpsfake (#46 item 5): a real gpsd (Debian's) fed an NMEA log written from a
# multi-body drive's truth, read live by canodom-gnss's client (its example `gpsd_fixes`).
#  (a) every fix received equals the NMEA file's fix of the same GNSS time (lat/lon to the
#      NMEA's 1e-7 minute resolution), and the received fixes are a contiguous run of the file's;
#  (b) gpsd killed mid-drive and started again: the client logs the loss, reconnects with
#      backoff, and receives fixes again.
# Loopback only: gpsd without -G listens on 127.0.0.1/::1. Starts and stops its own gpsd.
set -euo pipefail
cd "$(dirname "$0")/../.."
if ! command -v gpsfake >/dev/null; then
    apt-get install -y -q gpsd gpsd-clients >/dev/null
fi
work=$(mktemp -d)
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    # gpsfake's own gpsd: only those on our port.
    for p in $(ss -ltnpH "sport = :$port" 2>/dev/null | grep -o 'pid=[0-9]*' | cut -d= -f2 | sort -u); do
        kill "$p" 2>/dev/null || true
    done
    [ -n "${KEEP:-}" ] || rm -rf "$work"
}
port=$((29000 + RANDOM % 900))
trap cleanup EXIT

python3 -m venv "$work/venv"
"$work/venv/bin/pip" install -q numpy pynmea2 pymap3d
"$work/venv/bin/python" sim/multibody/fixes.py data/multibody/bmw320i/seed-5 --out "$work" \
    --window-s 60 --sigma-m 1.5 --jumps 2 --seed 3 >/dev/null
# The example as `cargo test --workspace` built it (no second build in CI; see the helper).
client=$(python3 .ci/test-artifact.py gnss example gpsd_fixes)

gpsd_pid() { ss -ltnpH "sport = :$port" | grep -o 'pid=[0-9]*' | head -1 | cut -d= -f2; }

echo "(a) fixes received live against the NMEA file"
gpsfake -1 -q -P "$port" -c 0.1 "$work/fixes.nmea" >"$work/gpsfake1.log" 2>&1 &
pids+=($!)
sleep 1
# gpsfake sends a sentence every 0.1 s: GGA, GST and RMC a fix, 18 s for the 60 fixes.
"$client" "127.0.0.1:$port" 24 1000 >"$work/a.csv" 2>"$work/a.log"
kill "$(gpsd_pid)" 2>/dev/null || true
"$work/venv/bin/python" - "$work/fixes.nmea" "$work/a.csv" <<'PY'
import datetime as dt, sys
nmea = {}
for line in open(sys.argv[1]):
    f = line.split(",")
    if f[0] == "$GPRMC":
        t = dt.datetime.strptime(f[9] + f[1], "%d%m%y%H%M%S.%f").replace(tzinfo=dt.timezone.utc).timestamp()
        lat = (int(f[3][:2]) + float(f[3][2:]) / 60) * (1 if f[4] == "N" else -1)
        lon = (int(f[5][:3]) + float(f[5][3:]) / 60) * (1 if f[6] == "E" else -1)
        nmea[round(t, 1)] = (lat, lon)
got = [l.strip().split(",") for l in open(sys.argv[2]) if l.startswith("fix,")]
timed = [(round(float(g[1]), 1), float(g[2]), float(g[3])) for g in got if g[1] != "NaN"]
untimed = len(got) - len(timed)
times = sorted(nmea)
bad = [(t, la, lo) for t, la, lo in timed if t not in nmea
       or abs(nmea[t][0] - la) > 2e-9 or abs(nmea[t][1] - lo) > 2e-9]
run = [t for t, _, _ in timed]
contiguous = run == times[times.index(run[0]):times.index(run[0]) + len(run)] if run else False
print(f"  NMEA fixes {len(nmea)}, received with a time {len(timed)} (+{untimed} before gpsd had a date), "
      f"first {len(nmea) - len(timed) - (len(times) - 1 - times.index(run[-1]) if run else 0)} lost while gpsd "
      f"identified the device; mismatches {len(bad)}; contiguous {contiguous}; ends at the file's last fix {run[-1] == times[-1] if run else False}")
if bad or not contiguous or not run or run[-1] != times[-1] or len(timed) < len(nmea) - 10:
    print("  FAIL", bad[:5]); sys.exit(1)
PY

echo "(b) gpsd killed mid-drive and started again"
gpsfake -1 -q -P "$port" -c 0.1 "$work/fixes.nmea" >"$work/gpsfake2.log" 2>&1 &
pids+=($!)
sleep 1
"$client" "127.0.0.1:$port" 22 1000 >"$work/b.csv" 2>"$work/b.log" &
cpid=$!
pids+=($cpid)
sleep 3
kill "$(gpsd_pid)"
before=$(grep -c '^fix' "$work/b.csv" || true)
sleep 3
gpsfake -1 -q -P "$port" -c 0.1 "$work/fixes.nmea" >"$work/gpsfake3.log" 2>&1 &
pids+=($!)
wait "$cpid"
after=$(grep -c '^fix' "$work/b.csv" || true)
connects=$(grep -c 'gpsd: connected' "$work/b.log" || true)
lost=$(grep -c 'connection lost or refused' "$work/b.log" || true)
echo "  fixes before the kill $before, in all $after; connects $connects, losses/refusals logged $lost"
grep -E 'reconnecting|lost' "$work/b.log" | sed 's/^/  log: /' | head -6
[ "$connects" -ge 2 ] && [ "$lost" -ge 1 ] && [ "$after" -gt "$before" ] || { echo "  FAIL"; exit 1; }
echo "gpsfake: ok"
