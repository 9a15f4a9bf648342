#!/usr/bin/env bash
# Time one fit of a photo alone, then JOBS fits of it side by side, as a batch runs them.
#
#   examples/batch/side_by_side.sh PHOTO [JOBS] [-- extra head360 options, e.g. --threads 1]
#
# Prints each fit's wall-clock seconds and the whole batch's. The fits are written into a
# temporary folder, removed at the end. The exit status is the number of fits that failed.
set -u
if [ $# -lt 1 ]; then
    echo "usage: $0 PHOTO [JOBS] [-- head360 options]" >&2
    exit 2
fi
photo=$1; jobs=${2:-4}
shift $(( $# >= 2 ? 2 : 1 ))
[ "${1:-}" = "--" ] && shift
work=$(mktemp -d) || exit 2
trap 'rm -rf "$work"' EXIT

one() {  # one fit; prints its seconds, or "failed"
    local start end
    start=$(date +%s.%N)
    if head360 "$@" fit "$photo" -o "$work/$RANDOM$RANDOM.h360" --quiet --json > /dev/null; then
        end=$(date +%s.%N)
        awk -v a="$start" -v b="$end" 'BEGIN { printf "%.1f\n", b - a }'
    else
        echo failed
    fi
}

echo "alone: $(one "$@") s"
start=$(date +%s.%N)
for i in $(seq "$jobs"); do one "$@" > "$work/time$i" & done
wait
end=$(date +%s.%N)
failed=0
for i in $(seq "$jobs"); do
    t=$(cat "$work/time$i")
    [ "$t" = failed ] && failed=$((failed + 1))
    echo "side by side $i of $jobs: $t s"
done
awk -v a="$start" -v b="$end" -v n="$jobs" 'BEGIN { printf "%d fits side by side: %.1f s in all\n", n, b - a }'
exit "$failed"
