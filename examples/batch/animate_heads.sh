#!/usr/bin/env bash
# Animate every head file in a folder with one ARKit stream, several at a time.
#
#   examples/batch/animate_heads.sh HEADS_DIR STREAM.csv OUT_DIR [JOBS] [-- animate options]
#
# Writes OUT_DIR/NAME.mp4 and NAME.result.json per head; failures are listed in
# OUT_DIR/failed.txt and do not stop the others; the exit status is the number of heads
# that failed (at most 125).
set -u
if [ $# -lt 3 ]; then
    echo "usage: $0 HEADS_DIR STREAM.csv OUT_DIR [JOBS] [-- head360 animate options]" >&2
    exit 2
fi
heads=$1; stream=$2; out=$3; jobs=${4:-2}
shift $(( $# >= 4 ? 4 : 3 ))
[ "${1:-}" = "--" ] && shift
mkdir -p "$out" || exit 2
rm -f "$out/failed.txt"
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}

find "$heads" -maxdepth 1 -type f -name '*.h360' -print0 | sort -z |
    xargs -0 -r -P "$jobs" -I{} bash -c '
        head=$1; stream=$2; out=$3; shift 3
        name=$(basename "${head%.h360}")
        if ! head360 animate "$head" --arkit "$stream" -o "$out/$name.mp4" --json --quiet \
                "$@" > "$out/$name.result.json" 2> "$out/$name.err"; then
            echo "$head" >> "$out/failed.txt"
        fi' _ {} "$stream" "$out" "$@"

failed=0
[ -f "$out/failed.txt" ] && failed=$(wc -l < "$out/failed.txt")
total=$(find "$heads" -maxdepth 1 -type f -name '*.h360' -print0 | tr -cd '\0' | wc -c)
echo "ran $total head(s), $failed failed" >&2
exit $(( failed > 125 ? 125 : failed ))
