#!/usr/bin/env bash
# A site left offline catches up with its office (issue 38): a site server
# forwarding to an office that is not running takes HOURS of a simulated
# TBM drive (inclinometer every INCL_PERIOD_S, laser every 120 s), then the
# office starts and the site sends its backlog. Prints the readings, the
# catch-up time from the office's start until it holds every reading (its
# store counted every 0.1 s; this includes the office's start and the
# site's back-off, at most 0.5 s, before it tries again), the rate over it
# and from the office's first commit on, both processes' CPU seconds, and
# the site's answer time to a status request during the catch-up.
#
#   tools/bench-forward-catchup.sh [HOURS] [INCL_PERIOD_S]   (default 24, 0.2)
#   DRIVE=pipe-jacking tools/bench-forward-catchup.sh [HOURS]  (a zupt
#     machine: FOG IMU at 100 Hz, level and odometer at 1 Hz)
#   BATCH=10 ...: the site takes the drive 10 readings a request (default
#     5000), so its outbox holds a row per 10 readings
#
# Needs a release build (cargo build --release) and python3.
set -euo pipefail
HOURS=${1:-24}
PERIOD=${2:-0.2}
BIN=${BIN:-target/release/tunnelnav}
WORK=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; cp "$WORK/office.log" /tmp/bench-office.log 2>/dev/null; cp "$WORK/site.log" /tmp/bench-site.log 2>/dev/null; rm -rf "$WORK"' EXIT
# Two free ports, held together while chosen so they differ.
read -r OFFICE_PORT SITE_PORT < <(python3 -c '
import socket
a, b = socket.socket(), socket.socket()
a.bind(("127.0.0.1", 0)); b.bind(("127.0.0.1", 0))
print(a.getsockname()[1], b.getsockname()[1])')

DRIVE=${DRIVE:-tbm}
if [ "$DRIVE" = tbm ]; then
    "$BIN" simulate tbm --hours "$HOURS" --incl-period-s "$PERIOD" --truth "$WORK/truth.csv" > "$WORK/drive.ndjson" 2>/dev/null
    DECLARATION='{"engines":{"attitude":{}}}'
else
    "$BIN" simulate pipe-jacking --case field --field-hours "$HOURS" --truth "$WORK/truth.csv" > "$WORK/drive.ndjson" 2>/dev/null
    DECLARATION='{"engines":{"zupt":{}}}'
fi
READINGS=$(wc -l < "$WORK/drive.ndjson")
RUST_LOG=${SITE_LOG:-warn} "$BIN" serve --listen "127.0.0.1:$SITE_PORT" --data-dir "$WORK/site" \
    --forward-to "http://127.0.0.1:$OFFICE_PORT" --site bench > /dev/null 2> "$WORK/site.log" &
SITE_PID=$!
sleep 1
curl -sf -X PUT "127.0.0.1:$SITE_PORT/api/v1/machines/tbm" -d "$DECLARATION" > /dev/null
split -l "${BATCH:-5000}" "$WORK/drive.ndjson" "$WORK/part_"
for part in "$WORK"/part_*; do
    curl -sf -X POST "127.0.0.1:$SITE_PORT/api/v1/machines/tbm/readings" \
        -H 'content-type: application/x-ndjson' --data-binary "@$part" > /dev/null
done

RUST_LOG=${OFFICE_LOG:-warn} "$BIN" serve --listen "127.0.0.1:$OFFICE_PORT" --data-dir "$WORK/office" > /dev/null 2> "$WORK/office.log" &
OFFICE_PID=$!
python3 - "$WORK" "$READINGS" "$SITE_PORT" "$SITE_PID" "$OFFICE_PID" <<'EOF'
import os, sqlite3, sys, time, urllib.request
work, readings, site_port, site_pid, office_pid = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5]
tick = os.sysconf("SC_CLK_TCK")
def cpu(pid):
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / tick
site_cpu0 = cpu(site_pid)
start = time.monotonic()
answers = []
db = os.path.join(work, "office", "tunnelnav.sqlite3")
count = 0
first = None
while count < readings:
    time.sleep(0.1)
    asked = time.monotonic()
    urllib.request.urlopen(f"http://127.0.0.1:{site_port}/api/v1/machines/tbm").read()
    answers.append(time.monotonic() - asked)
    if not os.path.exists(db):
        continue
    try:
        conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
        count = conn.execute("SELECT count(*) FROM readings").fetchone()[0]
        conn.close()
        if count > 0 and first is None:
            first = (time.monotonic(), count)
    except sqlite3.Error:
        pass
    if time.monotonic() - start > 600:
        sys.exit(f"not caught up after 600 s: {count} of {readings}")
elapsed = time.monotonic() - start
answers.sort()
transfer = time.monotonic() - first[0]
print(f"{readings} readings caught up in {elapsed:.2f} s from the office's start: {readings / elapsed:,.0f} readings/s; "
      f"{(readings - first[1]) / transfer:,.0f} readings/s from the first commit; CPU s: site {cpu(site_pid) - site_cpu0:.1f}, office {cpu(office_pid):.1f}; "
      f"the site's status answered in median {1000 * answers[len(answers) // 2]:.1f} ms, "
      f"worst {1000 * answers[-1]:.1f} ms ({len(answers)} requests)")
EOF
