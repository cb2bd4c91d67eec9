"""Session-wide pytest settings."""

import os
import sys

import pytest


class _ExitPastBlenderTeardown:
    """Ends the pytest process with its exit status once pytest is done, skipping C-level teardown.

    The bpy 4.5.4 module can deadlock at process exit: a static destructor in its sound code destroys a condition
    variable that its "delayed close" thread still waits on (gdb: ``GlobalState::~GlobalState`` in
    ``pthread_cond_destroy`` against ``delayed_close_thread_run``). It happens now and then, after everything has
    run and passed, and would leave the test run (and CI) hanging.
    """

    status = 0

    def pytest_sessionfinish(self, session, exitstatus):
        self.status = int(exitstatus)

    @pytest.hookimpl(trylast=True)
    def pytest_unconfigure(self, config):
        if "bpy" in sys.modules:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(self.status)


def pytest_configure(config):
    config.pluginmanager.register(_ExitPastBlenderTeardown(), "lbc-exit-past-blender-teardown")
