# Sourced by the PipeWire benches (sink_auto_vm.sh, daemon_cpu_pipewire.sh)
# after replay_common.sh: a private PipeWire session on the bench's bus
# (dbus-daemon, pipewire, wireplumber under a temporary XDG_RUNTIME_DIR),
# SDI's WirePlumber rule (both syntaxes) in its user configuration, and
# helpers to wait for nodes.

export XDG_RUNTIME_DIR=$tmp/runtime XDG_CONFIG_HOME=$tmp/config \
    XDG_STATE_HOME=$tmp/xstate XDG_DATA_HOME=$tmp/data
unset PIPEWIRE_REMOTE PIPEWIRE_RUNTIME_DIR DISPLAY WAYLAND_DISPLAY
mkdir -p -m 700 "$XDG_RUNTIME_DIR"
mkdir -p "$XDG_CONFIG_HOME/wireplumber/main.lua.d" "$XDG_CONFIG_HOME/wireplumber/wireplumber.conf.d"
cp udev/wireplumber/51-sdi-v4l2.lua "$XDG_CONFIG_HOME/wireplumber/main.lua.d/"
cp udev/wireplumber/51-sdi-v4l2.conf "$XDG_CONFIG_HOME/wireplumber/wireplumber.conf.d/"
pipewire >"$tmp/pipewire.log" 2>&1 &
pids+=($!)
for _ in $(seq 200); do pw-dump >/dev/null 2>&1 && break; sleep 0.2; done
wireplumber >"$tmp/wireplumber.log" 2>&1 &
pids+=($!)
pw_objects() { pw-dump 2>/dev/null || echo '[]'; }
wp_up() { pw_objects | /usr/bin/python3 -c 'import json,sys; sys.exit(not any(o.get("type")=="PipeWire:Interface:Client" and (o.get("info") or {}).get("props",{}).get("application.name")=="WirePlumber" for o in json.load(sys.stdin)))'; }
node_up() { pw_objects | /usr/bin/python3 -c 'import json,sys; sys.exit(not any((o.get("info") or {}).get("props",{}).get("node.name")==sys.argv[1] for o in json.load(sys.stdin)))' "$1"; }
for i in $(seq 300); do wp_up && break; sleep 0.4; done
wp_up || { echo "WirePlumber did not connect to PipeWire; its log:" >&2; tail -20 "$tmp/wireplumber.log" >&2; exit 1; }
echo "PipeWire session up (XDG_RUNTIME_DIR=$XDG_RUNTIME_DIR)"
