"""Run a command and write its exit status into ``$EXIT_CODE_FILE``: ``py-spy record -- CMD`` exits 0 whatever CMD
returns, so gpu_check.sh's ``DEMO_PYSPY=1`` runs the demo as ``py-spy record --subprocesses -- python3
benchmarks/gpu/exit_code.py timeout ... arcsem ...`` (this process waits, idle, so py-spy samples the job; a shell
wrapper lost the race with py-spy's exit)."""
import os
import subprocess
import sys

rc = subprocess.call(sys.argv[1:])
with open(os.environ["EXIT_CODE_FILE"], "w") as f:
    f.write(f"{rc}\n")
sys.exit(rc)
