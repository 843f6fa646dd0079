#!/usr/bin/env bash
# The certificate maker ships inside the package (mercury_dem/cluster/make-certs.sh); this is its old path.
exec bash "$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)/../../mercury_dem/cluster/make-certs.sh" "$@"
