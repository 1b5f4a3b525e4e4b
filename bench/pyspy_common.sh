# Sourced by bench/p31_pyspy.sh and bench/p31_startup.sh (NAME: the script's name for messages; PYTHON as theirs).
# go1_setup DIR: the device bundle with the Go1 robot (bench/device_setup.sh, its log in DIR/setup.txt) unless SETUP=0.
# pyspy_binary: $PYSPY, else py-spy on the PATH, in the device bundle's /tmp/site/bin or beside the interpreter; exits 2
# without one. learner_pid PARENT INTERVAL: the pid of PARENT's child running experiments/fastsac_go1.py (what
# bench/time_to_target.py starts: the learner process), polled every INTERVAL seconds for up to 30 s; exits 1 without.
go1_setup() {
  [ "${SETUP:-1}" = 1 ] || return 0
  ROBOTS="unitree_go1" source bench/device_setup.sh > "$1/setup.txt" 2>&1 || { cat "$1/setup.txt"; exit 1; }
  head -3 "$1/setup.txt"
}
pyspy_binary() {
  local py=${PYTHON:-python3} bin
  bin=${PYSPY:-$(command -v py-spy || { [ -x /tmp/site/bin/py-spy ] && echo /tmp/site/bin/py-spy; } \
    || echo "$(dirname "$("$py" -c 'import sys; print(sys.executable)')")/py-spy")}
  [ -x "$bin" ] || { echo "$NAME: no py-spy binary (bench/device_bundle.sh bundles its wheel; or set PYSPY)" >&2; exit 2; }
  echo "$bin"
}
learner_pid() {
  local parent=$1 interval=$2 p
  for _ in $(seq "$(awk "BEGIN { print int(30 / $interval) }")"); do
    for p in /proc/[0-9]*; do
      [ "$(cut -d' ' -f4 "$p/stat" 2>/dev/null)" = "$parent" ] && grep -q fastsac_go1 "$p/cmdline" 2>/dev/null \
        && echo "${p#/proc/}" && return
    done
    sleep "$interval"
  done
  echo "$NAME: the learner process did not start" >&2; exit 1
}
