#!/usr/bin/env bash
# The project's two entry points (see README):
#   bash run.sh main   -- the whole Snakemake DAG on config/config.yaml with the builtin engine
#   bash run.sh test   -- the linters (ruff, snakefmt, snakemake --lint), then the test suite
# Each makes (or reuses) the virtual environment .venv from environment.txt first.
set -euo pipefail
cd "$(dirname "$0")"
VENV=.venv

ensure_venv() {
    if ! python3 -m venv --help >/dev/null 2>&1 || ! python3 -c 'import ensurepip' 2>/dev/null; then
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
            apt-get update -q && apt-get install -y -q python3-venv python3-dev gcc
        else
            echo "run.sh: python3 with venv is needed (Debian: apt-get install python3-venv)" >&2; exit 1
        fi
    fi
    local stamp="$VENV/.environment.sha256" want
    want=$(sha256sum environment.txt pyproject.toml | sha256sum | cut -d' ' -f1)
    if [ ! -x "$VENV/bin/python" ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
        echo "run.sh: installing environment.txt into $VENV"
        python3 -m venv "$VENV"
        "$VENV/bin/pip" install -q --upgrade pip
        "$VENV/bin/pip" install -q -r environment.txt
        "$VENV/bin/pip" install -q --no-deps --no-build-isolation -e .
        echo "$want" > "$stamp"
    fi
}

# Optional system packages: LIGGGHTS (the real-solver fallback), SLURM and munge (the cluster test),
# Chromium (the HTML report opened in a headless browser). Tests that need them skip, saying why,
# where they cannot be installed.
ensure_optional_apt() {
    local missing=()
    command -v liggghts >/dev/null || missing+=(liggghts)
    command -v slurmctld >/dev/null || missing+=(slurm-wlm)
    command -v munged >/dev/null || missing+=(munge)
    command -v chromium >/dev/null || missing+=(chromium)
    [ ${#missing[@]} -eq 0 ] && return 0
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "run.sh: installing optional ${missing[*]} from Debian"
        { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${missing[@]}"; } \
            >/tmp/run.sh-apt.log 2>&1 || echo "run.sh: could not install ${missing[*]} (see /tmp/run.sh-apt.log); their tests will skip"
    else
        echo "run.sh: not root or no apt-get; tests needing ${missing[*]} will skip"
    fi
}

# The arguments that make `run.sh main` end by writing Snakemake's HTML report, results/report.html:
# none when the arguments ask for something other than running the DAG (a dry run, an unlock, a
# partial run with --until, a report of their own, a listing, ...).
report_args() {
    local arg
    for arg in "$@"; do
        case "$arg" in
            -n* | -[!-]*n* | --dry-run | --dryrun | --unlock | --until | -U | --omit-from | -O | --touch | -t | \
                --lint | --report | --report-after-run | --summary | -S | --detailed-summary | -D | --dag | \
                --rulegraph | --filegraph | --list-rules | -l | --list-target-rules | --lt | --list-changes | \
                --lc | --delete-all-output | --delete-temp-output | --cleanup-metadata | --cm | --help | -h | \
                --version | -v | --containerize | --export-cwl | --conda-create-envs-only | --archive | \
                --generate-unit-tests)
                return 0
                ;;
        esac
    done
    echo "--report results/report.html --report-after-run"
}

case "${1:-}" in
    main)
        ensure_venv
        shift
        # shellcheck disable=SC2046  # report_args prints separate words on purpose
        exec "$VENV/bin/python" -m snakemake --profile workflow/profiles/default "$@" $(report_args "$@")
        ;;
    test)
        ensure_venv
        ensure_optional_apt
        shift
        echo "run.sh: linting first: ruff check, ruff format --check, snakefmt --check, snakemake --lint"
        if ! { "$VENV/bin/ruff" check . && "$VENV/bin/ruff" format --check . \
            && "$VENV/bin/snakefmt" --check Snakefile workflow/ \
            && "$VENV/bin/python" -m snakemake --lint --profile workflow/profiles/default; }; then
            echo "run.sh: lint failed (see above); fix it before the tests run" >&2; exit 1
        fi
        # two workers, one per core, a test file per worker at a time, the longest first
        # (tests/conftest.py); the slowest tests in the log, to keep the suite short on 2 cores
        exec "$VENV/bin/python" -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder --durations=15 "$@"
        ;;
    *)
        echo "usage: bash run.sh main [snakemake args] | bash run.sh test [pytest args]" >&2; exit 2
        ;;
esac
