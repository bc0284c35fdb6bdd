#!/bin/sh
# Re-creates static/vendor/leaflet/, leaflet-geoman/, codemirror/ and chartjs/ from the npm
# packages (see README.md here). Needs npm and the npm registry; `make test` and `make demo` never run
# it: the copies are part of the repository, so nothing is fetched at run time.
#
#   sh static/vendor/update.sh                     # the versions below
#   LEAFLET=1.9.4 GEOMAN=2.20.2 CODEMIRROR=5.65.21 CHARTJS=4.5.1 sh static/vendor/update.sh
set -eu

LEAFLET=${LEAFLET:-1.9.4}
GEOMAN=${GEOMAN:-2.20.2}
CODEMIRROR=${CODEMIRROR:-5.65.21}
CHARTJS=${CHARTJS:-4.5.1}

here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

cd "$work"
npm init -y >/dev/null
npm install --no-audit --no-fund --ignore-scripts --omit=dev \
    "leaflet@$LEAFLET" "@geoman-io/leaflet-geoman-free@$GEOMAN" >/dev/null
modules="$work/node_modules"

# The source maps are not shipped; their references go, or collectstatic's manifest would
# look for them.
copy() {
    sed -e '/^\/[/*]# sourceMappingURL=/d' "$1" >"$2"
}

leaflet="$here/leaflet"
rm -rf "$leaflet"
mkdir -p "$leaflet/images"
copy "$modules/leaflet/dist/leaflet.js" "$leaflet/leaflet.js"
copy "$modules/leaflet/dist/leaflet.css" "$leaflet/leaflet.css"
cp "$modules/leaflet/dist/images/"*.png "$leaflet/images/"
cp "$modules/leaflet/LICENSE" "$leaflet/LICENSE"

geoman="$here/leaflet-geoman"
package="$modules/@geoman-io/leaflet-geoman-free"
rm -rf "$geoman"
mkdir -p "$geoman"
copy "$package/dist/leaflet-geoman.min.js" "$geoman/leaflet-geoman.min.js"
copy "$package/dist/leaflet-geoman.css" "$geoman/leaflet-geoman.css"
cp "$package/LICENSE" "$geoman/LICENSE"
# leaflet-geoman.min.js bundles its dependencies: their licences go with it.
{
    echo "Licences of the packages bundled in leaflet-geoman.min.js (@geoman-io/leaflet-geoman-free $GEOMAN)."
    npm ls --all --parseable | grep '/node_modules/' | sort -u | while read -r dir; do
        name=$(node -p "require('$dir/package.json').name")
        case "$name" in
        leaflet | @geoman-io/leaflet-geoman-free | @types/*) continue ;;
        esac
        version=$(node -p "require('$dir/package.json').version")
        license=$(node -p "require('$dir/package.json').license")
        echo
        echo "==== $name $version ($license)"
        for file in "$dir"/LICENSE* "$dir"/LICENCE* "$dir"/license*; do
            if [ -f "$file" ]; then
                echo
                cat "$file"
            fi
        done
    done
} >"$geoman/THIRD-PARTY-LICENSES"

# The program editor and the VV page's chart, installed apart so that Geoman's list of bundled
# packages above stays its own.
mkdir "$work/pages"
cd "$work/pages"
npm init -y >/dev/null
npm install --no-audit --no-fund --ignore-scripts --omit=dev \
    "codemirror@$CODEMIRROR" "chart.js@$CHARTJS" >/dev/null
modules="$work/pages/node_modules"

codemirror="$here/codemirror"
rm -rf "$codemirror"
mkdir -p "$codemirror/lib" "$codemirror/mode/javascript" "$codemirror/addon/edit"
copy "$modules/codemirror/lib/codemirror.js" "$codemirror/lib/codemirror.js"
copy "$modules/codemirror/lib/codemirror.css" "$codemirror/lib/codemirror.css"
copy "$modules/codemirror/mode/javascript/javascript.js" "$codemirror/mode/javascript/javascript.js"
copy "$modules/codemirror/addon/edit/matchbrackets.js" "$codemirror/addon/edit/matchbrackets.js"
cp "$modules/codemirror/LICENSE" "$codemirror/LICENSE"

chart="$here/chartjs"
rm -rf "$chart"
mkdir -p "$chart"
copy "$modules/chart.js/dist/chart.umd.min.js" "$chart/chart.umd.min.js"
cp "$modules/chart.js/LICENSE.md" "$chart/LICENSE"
# chart.umd.min.js bundles @kurkle/color: its licence goes with it.
{
    kurkle="$modules/@kurkle/color"
    echo "Licences of the packages bundled in chart.umd.min.js (chart.js $CHARTJS)."
    echo
    echo "==== @kurkle/color $(node -p "require('$kurkle/package.json').version") ($(node -p "require('$kurkle/package.json').license"))"
    echo
    cat "$kurkle/LICENSE.md"
} >"$chart/THIRD-PARTY-LICENSES"

echo "leaflet $LEAFLET -> $leaflet"
echo "@geoman-io/leaflet-geoman-free $GEOMAN -> $geoman"
echo "codemirror $CODEMIRROR -> $codemirror"
echo "chart.js $CHARTJS -> $chart"
