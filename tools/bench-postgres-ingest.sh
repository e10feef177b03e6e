#!/bin/sh
# Batched ingest into PostgreSQL against a raw COPY of the same rows
# (issue 37's bar: ingest >= 0.5x COPY), on this machine: server, load
# generator and PostgreSQL share its cores.
#
#   cargo build --release && tools/bench-postgres-ingest.sh [MACHINES] [READINGS_PER_MACHINE]
#
# 1. A fresh cluster (initdb in a temporary directory, as the postgres user
#    when run as root; PostgreSQL's defaults, fsync on).
# 2. `serve --store` on it, `load --mode batch --url` posts the readings
#    (NDJSON batches of 1000, fused, readings and estimates committed
#    before each answer): readings/s as `load` reports it.
# 3. The stored readings are written out with COPY ... BINARY, the table
#    emptied, and the same rows loaded back with `COPY readings FROM`
#    (same partitions, indexes and keys): rows/s.
# Prints both and their ratio.
set -eu

machines=${1:-20}
per_machine=${2:-20000}
exe=${TUNNELNAV:-target/release/tunnelnav}
pg_bin=${TUNNELNAV_PG_BIN:-$(ls -d /usr/lib/postgresql/*/bin | sort -V | tail -n 1)}
[ -x "$exe" ] || { echo "no $exe: cargo build --release first" >&2; exit 1; }
[ -x "$pg_bin/initdb" ] || { echo "no PostgreSQL under $pg_bin" >&2; exit 1; }

work=$(mktemp -d /tmp/tunnelnav-pgbench-XXXXXX)
chmod 755 "$work"
as_pg() {
    if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
cleanup() {
    [ -n "${server:-}" ] && kill "$server" 2>/dev/null || true
    as_pg "$pg_bin/pg_ctl" -D "$work/pg" -m fast stop >/dev/null 2>&1 || true
    rm -rf "$work"
}
trap cleanup EXIT
mkdir "$work/pg" "$work/dump" "$work/data"
[ "$(id -u)" = 0 ] && chown postgres "$work/pg" "$work/dump"
as_pg "$pg_bin/initdb" -D "$work/pg" -U postgres --auth=trust >/dev/null
as_pg "$pg_bin/pg_ctl" -D "$work/pg" -l "$work/pg/log" -w \
    -o "-p $port -k $work/pg -c listen_addresses=127.0.0.1" start >/dev/null
psql() { "$pg_bin/psql" -X -q -h 127.0.0.1 -p "$port" -U postgres -v ON_ERROR_STOP=1 "$@"; }
psql -c "CREATE DATABASE bench"
url="postgres://postgres@127.0.0.1:$port/bench"

RUST_LOG=warn "$exe" serve --listen 127.0.0.1:0 --store "$url" --data-dir "$work/data" \
    > "$work/serve.out" 2>&1 &
server=$!
for _ in $(seq 100); do
    grep -q "^listening on " "$work/serve.out" && break
    sleep 0.1
done
base=$(sed -n 's/^listening on //p' "$work/serve.out")
[ -n "$base" ] || { cat "$work/serve.out" >&2; exit 1; }
"$exe" load --mode batch --url "$base" --machines "$machines" --readings "$per_machine" \
    --concurrency 8 --batch 1000 | tee "$work/load.out"
kill "$server"; wait "$server" 2>/dev/null || true; server=
ingest=$(sed -n 's/.* \([0-9][0-9]*\) readings\/s.*/\1/p' "$work/load.out" | head -n 1)

rows=$(psql -d bench -At -c "SELECT count(*) FROM readings")
psql -d bench -c "COPY (SELECT id, machine_id, t, sensor, body FROM readings ORDER BY id) \
    TO '$work/dump/readings.bin' (FORMAT binary)"
psql -d bench -c "TRUNCATE readings" -c "CHECKPOINT"
start=$(date +%s.%N)
psql -d bench -c "COPY readings (id, machine_id, t, sensor, body) \
    FROM '$work/dump/readings.bin' (FORMAT binary)"
end=$(date +%s.%N)
copied=$(psql -d bench -At -c "SELECT count(*) FROM readings")
[ "$copied" = "$rows" ] || { echo "COPY loaded $copied of $rows rows" >&2; exit 1; }
python3 - "$rows" "$start" "$end" "$ingest" <<'EOF'
import sys
rows, start, end, ingest = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
copy = rows / (end - start)
print(f"raw COPY of the same {rows} readings: {end - start:.2f} s, {copy:.0f} rows/s")
print(f"batched ingest {ingest:.0f} readings/s = {ingest / copy:.2f} x COPY (bar: >= 0.5)")
EOF
