"""``python -m harness headline [--check]`` (from ``workflows/benchmarks``)."""

import sys

from harness import headline

if __name__ == "__main__":
    argv = sys.argv[1:]
    if not argv or argv[0] != "headline":
        sys.exit("usage: python -m harness headline [--check] [--doc PATH] [--records DIR]")
    sys.exit(headline.main(argv[1:]))
