# Sourced by the grind bench scripts: what the figures were measured on. $src = the source tree.
# The commit says when core/grind or tools/grind differ from it (uncommitted work measured).
echo "== machine"
echo "date: $(date -u +%Y-%m-%dT%H:%M:%SZ)"
echo "commit: $(git -C "$src" rev-parse HEAD)$(git -C "$src" diff --quiet HEAD -- core/grind tools/grind || echo ' + uncommitted core/grind, tools/grind')"
lscpu | grep -E '^(CPU\(s\)|Model name|Thread\(s\) per core):' || true
uname -r
g++ --version | head -1
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"
