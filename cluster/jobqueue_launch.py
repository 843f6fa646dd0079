#!/usr/bin/env python3
"""The batch-system launcher, kept at its old path: it is ``mercury-dem cluster`` (mercury_dem/cluster/jobqueue.py)."""

import sys

from mercury_dem.cluster.jobqueue import main

if __name__ == "__main__":
    sys.exit(main())
