#!/usr/bin/env bash
# Run the whole test suite N times in a row (default 10) and list every test that failed at
# least once, with how often: the check that the suite never fails by chance.
#
#   tests/soak_suite.sh [N] [pytest options...]      e.g. tests/soak_suite.sh 10 -m 'not slow'
#
# Each run's full output is kept in a directory printed at the end. PYTHON picks the
# interpreter (default .venv/bin/python, as README.md sets it up).
set -uo pipefail
cd "$(dirname "$0")/.."
runs=${1:-10}
shift $(( $# > 0 ? 1 : 0 ))
python=${PYTHON:-.venv/bin/python}
logs=$(mktemp -d -t pneumad-soak-XXXX)
failed_runs=0
for i in $(seq 1 "$runs"); do
    start=$(date +%s)
    "$python" -m pytest -q -p no:cacheprovider -rfE "$@" > "$logs/run-$i.log" 2>&1
    code=$?
    [ "$code" -ne 0 ] && failed_runs=$((failed_runs + 1))
    echo "run $i/$runs: exit $code, $(( $(date +%s) - start )) s: $(tail -n 1 "$logs/run-$i.log")"
done
echo
echo "tests that failed at least once ($failed_runs of $runs runs failed):"
grep -h -E '^(FAILED|ERROR) ' "$logs"/run-*.log | sed -E 's/ - .*//' | sort | uniq -c | sort -rn || echo "  none"
echo "logs: $logs"
exit $(( failed_runs > 0 ))
