"""`python -m dockhil.process [--keys KEY_FILE] SPEC_JSON`: a node process (dockhil.runtime.process).

The launcher starts nodes by this name, which every install answers to, so its command line works on
a host whose dockhil is older or newer than its own."""

import sys

from dockhil.runtime.process import main

sys.exit(main())
