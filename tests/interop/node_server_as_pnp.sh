#!/usr/bin/env bash
# Stand-in for the pnp binary, backed by the node-opcua reference server, so the
# interop harness can be checked on its own:
#   tests/interop/node_server_as_pnp.sh ua serve --port PORT [--user NAME:PASSWORD]...
# (tests/interop/run_node_self_test.sh uses it.) node_server.js always accepts anonymous and
# operator/secret, so --user arguments are accepted and ignored; so are --nodeset and
# --instance (node_server.js loads no Robotics model: node_client.js skips those checks).
set -euo pipefail
usage() {
    echo "usage: $0 ua serve --port PORT [--no-register | --allow-none | --insecure] [--user NAME:PASSWORD | --nodeset FILE | --instance SPEC]..." >&2
    exit 2
}
if [[ $# -lt 4 || "$1" != "ua" || "$2" != "serve" || "$3" != "--port" ]]; then
    usage
fi
rest=("${@:5}")
while ((${#rest[@]} > 0)); do
    # node_server.js registers nowhere and always offers None, so these flags change nothing
    if [[ "${rest[0]}" =~ ^--(no-register|allow-none|insecure)$ ]]; then
        rest=("${rest[@]:1}")
        continue
    fi
    [[ "${rest[0]}" =~ ^--(user|nodeset|instance)$ && ${#rest[@]} -ge 2 ]] || usage
    rest=("${rest[@]:2}")
done
exec node "$(dirname "${BASH_SOURCE[0]}")/node_server.js" "$4"
