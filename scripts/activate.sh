# Workspace environment for bash. Use it with `source`, from any directory:
#
#     source scripts/activate.sh
#
# It activates .venv (ROS 2 Jazzy from the PyPI wheels), sources install/setup.bash (this
# workspace's packages), adds the venv to AMENT_PREFIX_PATH (so ament_index finds the wheels'
# packages) and thereby puts `apf-swarm` (a wrapper in .venv/bin) on PATH. The node
# executables stay in install/apf_swarm_nodes/lib/apf_swarm_nodes, off PATH.
# Run `make setup` first. Safe to source twice and from `set -eu` scripts.

if [ -z "${BASH_VERSION:-}" ]; then
    echo "scripts/activate.sh: needs bash (source it from bash)" >&2
    return 1 2>/dev/null || exit 1
fi
if [ "${BASH_SOURCE[0]}" = "$0" ]; then
    echo "scripts/activate.sh: source this file, do not run it: source ${BASH_SOURCE[0]}" >&2
    exit 1
fi

_apf_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)"

if [ ! -x "$_apf_root/.venv/bin/python" ] || [ ! -f "$_apf_root/install/setup.bash" ]; then
    echo "scripts/activate.sh: workspace not built; run: make -C '$_apf_root' setup" >&2
    unset _apf_root
    return 1
fi

# The venv and colcon scripts are not written for `set -u`: relax it while they run.
case "$-" in *u*) _apf_had_u=1; set +u ;; *) _apf_had_u= ;; esac

# shellcheck disable=SC1091
source "$_apf_root/.venv/bin/activate"
# shellcheck disable=SC1091
source "$_apf_root/install/setup.bash"

case ":${AMENT_PREFIX_PATH:-}:" in
    *":$_apf_root/.venv:"*) ;;
    *) export AMENT_PREFIX_PATH="${AMENT_PREFIX_PATH:+$AMENT_PREFIX_PATH:}$_apf_root/.venv" ;;
esac
export APF_SWARM_ROOT="$_apf_root"
hash -r 2>/dev/null

[ -n "$_apf_had_u" ] && set -u
unset _apf_root _apf_had_u
true
