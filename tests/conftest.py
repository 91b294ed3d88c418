import sys
from pathlib import Path

import pytest

# Tests import the packages from this checkout, installed or not.
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# numpy in the tests as in the command line: one BLAS thread (tools/cli.py sets it before numpy is imported), so two
# test workers on two cores do not start four threads.
import naocal.tools.cli  # noqa: E402,F401

MOCK_RUN_SEED = 5  # the shared calibration run's mock (mock_run below)


def pytest_collection_modifyitems(config, items):
    """For `pytest -n 2` (README's test command; pyproject.toml adds --dist=loadfile, so that a module's fixtures
    are made once, on the worker that runs the module): the modules with end-to-end (slow) tests come first, so
    the long tests start early and the short ones fill the end instead of one long module running alone at the
    end. Modules stay whole and keep their order."""
    slow_modules = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in slow_modules)  # stable


@pytest.fixture(scope="session")
def mock_run(tmp_path_factory):
    """One whole calibration of the ideal mock (seed 5, default plan, as `naocal calibrate --backend mock --mock
    ideal --seed 5` runs it), shared: tests/test_agent_mock.py checks the run, tests/test_diagnostics_mock.py
    diagnoses its dataset. (mock, DIR, result, context, number of commands the calibration sent)."""
    from naocal.agent.calibrate import calibrate
    from naocal.agent.states import AgentSettings
    from naocal.backends.mock import MockBackend

    out = tmp_path_factory.mktemp("mock_calibration")
    mock = MockBackend(MOCK_RUN_SEED)
    try:
        result, ctx = calibrate(mock, out, AgentSettings(seed=0, progress_bar=False),
                                backend_label=f"mock {MOCK_RUN_SEED}", truth=mock.truth_dict())
        yield mock, out, result, ctx, len(mock.command_log)
    finally:
        mock.close()

