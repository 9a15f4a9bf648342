#!/usr/bin/env bash
# Fit every photo in a folder, several at a time, and keep going when one fails.
#
#   examples/batch/fit_folder.sh PHOTOS_DIR OUT_DIR [JOBS] [-- extra head360 fit options]
#
# For each photo NAME.jpg|jpeg|png|heic|heif|webp|tif|tiff|bmp it writes OUT_DIR/NAME.h360 (+ preview and summary),
# OUT_DIR/NAME.result.json (head360's --json answer, also for failures) and NAME.err
# (warnings and errors). Photos that share a NAME (x.jpg and x.png) are written as
# NAME_jpg, NAME_png, so that neither overwrites the other. Failed photos are listed in OUT_DIR/failed.txt. The exit status
# is the number of photos that failed (at most 125), so 0 means all fitted.
# Collect the results into one CSV with:  python examples/batch/collect.py OUT_DIR
set -u
if [ $# -lt 2 ]; then
    echo "usage: $0 PHOTOS_DIR OUT_DIR [JOBS] [-- head360 fit options]" >&2
    exit 2
fi
photos=$1; out=$2; jobs=${3:-2}
shift $(( $# >= 3 ? 3 : 2 ))
[ "${1:-}" = "--" ] && shift
mkdir -p "$out" || exit 2
rm -f "$out/failed.txt"
# one torch thread per job, unless the caller chose otherwise
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}

list_photos() {
    # the formats head360 reads (HEIC, an iPhone's, with the optional pillow-heif)
    find "$photos" -maxdepth 1 -type f \( -iname '*.jpg' -o -iname '*.jpeg' -o -iname '*.png' \
        -o -iname '*.heic' -o -iname '*.heif' -o -iname '*.webp' -o -iname '*.tif' \
        -o -iname '*.tiff' -o -iname '*.bmp' \) -print0 | sort -z
}
# the names two or more photos share, one a line
shared=$(mktemp) || exit 2
trap 'rm -f "$shared"' EXIT
while IFS= read -r -d '' photo; do
    base=${photo##*/}
    printf '%s\n' "${base%.*}"
done < <(list_photos) | sort | uniq -d > "$shared"
total=$(list_photos | tr -cd '\0' | wc -c)

list_photos |
    xargs -0 -r -P "$jobs" -I{} bash -c '
        photo=$1; out=$2; shared=$3; shift 3
        base=${photo##*/}
        name=${base%.*}
        if grep -Fxq -- "$name" "$shared"; then
            name="${name}_${base##*.}"
        fi
        if ! head360 fit "$photo" -o "$out/$name.h360" --json --quiet "$@" \
                > "$out/$name.result.json" 2> "$out/$name.err"; then
            echo "$photo" >> "$out/failed.txt"
        fi' _ {} "$out" "$shared" "$@"

failed=0
[ -f "$out/failed.txt" ] && failed=$(wc -l < "$out/failed.txt")
echo "ran $total photo(s), $failed failed" >&2
exit $(( failed > 125 ? 125 : failed ))
