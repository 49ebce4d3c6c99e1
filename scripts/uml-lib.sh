# Shared by scripts/uml-vcan and scripts/uml-systemd (sourced, not run): booting
# User-Mode Linux (UML), a Linux kernel that runs as an ordinary process, with the
# host's files as its root (hostfs) and a script of ours as its init.
#
# The caller sets `uml_name` (the prefix of log lines) and `repo` before sourcing.
#
# UML's own exit status does not carry a test's result: the guest writes its results
# to files on the host (hostfs) and the caller reads them after the guest powers off.

# AVX-512 registers are not switched between the guest's threads (scripts/uml-xstate.c):
# every process in the guest keeps glibc's string functions on their AVX2 versions.
uml_glibc_tunables=glibc.cpu.hwcaps=-AVX512F,-AVX512VL,-AVX512BW,-AVX512DQ,-AVX512CD

uml_log() { printf '%s: %s\n' "$uml_name" "$*" >&2; }
uml_die() {
    uml_log "error: $*"
    exit 1
}

# Installs the Debian packages of the commands named as `command:package` that are
# missing (needs root).
uml_install_missing() {
    local missing=() pair
    for pair in "$@"; do
        command -v "${pair%%:*}" >/dev/null 2>&1 || [[ -x /usr/sbin/${pair%%:*} ]] ||
            missing+=("${pair#*:}")
    done
    ((${#missing[@]} == 0)) && return 0
    uml_log "installing ${missing[*]}"
    [[ $(id -u) -eq 0 ]] || uml_die "need root to apt-get install ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq "${missing[@]}" >/dev/null
}

# The selection scripts/test builds its tests with (stage 4: the workspace with the OPC
# UA server's feature): the suites take their executables from that one build, so a CI
# run compiles nothing again.
uml_test_selection=(--workspace --features millgate/opcua,millgate-tests/opcua)

# Builds the test targets of `cargo test ARGS... --no-run` on the host (compiling in
# the guest is slow) and prints the executables of the integration test $1 among
# them, one a line.
uml_test_executables() {
    local name=$1 build_json
    shift
    build_json=$(cd "$repo" && cargo test "$@" --no-run --message-format=json) ||
        uml_die "cargo test $* --no-run failed"
    printf '%s\n' "$build_json" |
        grep '"reason":"compiler-artifact"' |
        grep '"kind":\["test"\]' |
        grep "\"name\":\"$name\"" |
        sed -n 's/.*"executable":"\([^"]*\)".*/\1/p'
}

# Prints the shell lines a guest's init starts with: PATH, the glibc tunables, /proc
# and /sys, loopback up, and `$modules`, the folder of UML's kernel modules.
uml_guest_prelude() {
    cat <<EOF
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin HOME=/root
export GLIBC_TUNABLES=$uml_glibc_tunables
mount -t proc proc /proc
mount -t sysfs sys /sys
ip link set lo up
modules=/usr/lib/uml/modules/\$(uname -r)/kernel
[ -d "\$modules" ] || modules=\$(ls -d /usr/lib/uml/modules/*/kernel | head -n 1)
EOF
}

# Prints the guest lines that load SocketCAN and create the vcan interface $1; they
# set `ok=0` when something fails. Load by full path: there is no depmod tree for UML.
uml_guest_vcan() {
    cat <<EOF
for module in net/can/can.ko net/can/can-raw.ko drivers/net/can/dev/can-dev.ko \\
        drivers/net/can/vcan.ko; do
    insmod "\$modules/\$module" || ok=0
done
ip link add dev $1 type vcan && ip link set up $1 || ok=0
EOF
}

# Boots UML with the host's / as root and the script $2 as init, within $3 seconds,
# with $4 of memory and the kernel arguments after them (`ro` or `rw` among them);
# the console goes to $1/console.log. Returns linux.uml's exit status.
uml_boot() {
    local work=$1 init=$2 timeout_s=$3 memory=$4
    shift 4
    # UML 6.1 cannot restore FPU state on hosts with a larger XSAVE area (AVX-512,
    # PKRU, AMX): scripts/uml-xstate.c bridges the sizes (see its comment).
    local preload=()
    if command -v cc >/dev/null 2>&1; then
        cc -O2 -shared -fPIC -o "$work/uml-xstate.so" "$repo/scripts/uml-xstate.c" -ldl ||
            uml_die "cannot build scripts/uml-xstate.c"
        preload=(env LD_PRELOAD="$work/uml-xstate.so")
    else
        uml_log "no C compiler: UML's FPU state handling not bridged (hosts with AVX-512 or AMX crash the guest)"
    fi
    # The guest's memory is a file in TMPDIR; keep it on the host's /tmp (sparse).
    local status=0
    TMPDIR=/tmp timeout --kill-after=10 "$timeout_s" "${preload[@]}" linux.uml \
        mem="$memory" root=/dev/root rootfstype=hostfs rootflags=/ "$@" \
        init="$init" con=null con0=fd:0,fd:1 \
        </dev/null >"$work/console.log" 2>&1 || status=$?
    return "$status"
}

# Writes the script $1 that runs each test executable (the arguments after the first
# five) from the folder $3 with the environment assignments $4 and the ignored tests
# included, one test at a time, passing them the (quoted) test arguments $5; output
# is appended to $2/output, one exit status per executable to $2/status. It runs on
# the host or in the guest: both see the same paths.
uml_write_runner() {
    local script=$1 work=$2 folder=$3 environment=$4 test_args=$5
    shift 5
    cat >"$script" <<EOF
#!/bin/sh
cd "$folder" || { echo "the guest cannot enter $folder" >>"$work/output"; exit 1; }
export $environment RUST_BACKTRACE=1
for binary in $*; do
    echo "== \$binary" >>"$work/output"
    "\$binary" --include-ignored --test-threads=1 --show-output $test_args >>"$work/output" 2>&1
    echo \$? >>"$work/status"
done
EOF
    chmod +x "$script"
}

# Prints the output the runner of uml_write_runner left in $1 and the line
# `$2 suite: N passed, M failed ($3)`; fails unless each of the $4 executables ran and
# passed and at least one test ran.
uml_report() {
    local work=$1 suite=$2 where=$3 executables=$4
    [[ -f $work/output ]] || uml_die "the tests produced no output"
    cat "$work/output"
    local passed=0 failed=0 count runs=0 statuses_ok=1 status
    while read -r count; do passed=$((passed + count)); done < <(
        sed -n 's/^test result: .* \([0-9][0-9]*\) passed;.*/\1/p' "$work/output")
    while read -r count; do failed=$((failed + count)); done < <(
        sed -n 's/^test result: .* \([0-9][0-9]*\) failed;.*/\1/p' "$work/output")
    if [[ -f $work/status ]]; then
        while read -r status; do
            runs=$((runs + 1))
            [[ $status == 0 ]] || statuses_ok=0
        done <"$work/status"
    fi
    ((runs == executables)) || statuses_ok=0
    echo "$suite suite: $passed passed, $failed failed ($where)"
    ((statuses_ok == 1)) || uml_die "a test executable failed or did not run"
    ((failed == 0)) || uml_die "$failed test(s) failed"
    ((passed > 0)) || uml_die "no test ran"
}
