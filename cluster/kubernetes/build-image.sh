#!/usr/bin/env bash
# Build the mercury-dem image from the repository root, and optionally push it.
#
#   cluster/kubernetes/build-image.sh [IMAGE]          (default IMAGE: mercury-dem:0.1.0)
#   PUSH=1 cluster/kubernetes/build-image.sh registry.example.org/me/mercury-dem:0.1.0
#
# The manifests next to this file name mercury-dem:0.1.0; when you push to a registry,
# replace that name in them (sed -i 's|mercury-dem:0.1.0|registry.../mercury-dem:0.1.0|' *.yaml).
set -euo pipefail
IMAGE="${1:-mercury-dem:0.1.0}"
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
DOCKER_BUILDKIT=1 docker build -f "$repo/cluster/kubernetes/Dockerfile" -t "$IMAGE" "$repo"
docker run --rm "$IMAGE" --help > /dev/null   # the entry point answers
[ "${PUSH:-0}" = 1 ] && docker push "$IMAGE"
echo "built $IMAGE"
