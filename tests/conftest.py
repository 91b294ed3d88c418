import sys
from pathlib import Path

import pytest

# Tests import the packages from this checkout, installed or not.
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# numpy in the tests as in the command line: one BLAS thread (tools/cli.py sets it before numpy is imported), so two
# test workers on two cores do not start four threads.
import tools.cli  # noqa: E402,F401

MOCK_RUN_SEED = 5  # the shared calibration run's mock (mock_run below)


def pytest_collection_modifyitems(config, items):
    """Two things for `pytest -n 2` (README's test command; pyproject.toml adds --dist=loadgroup):

    - the tests that share a module- or session-scoped fixture of this directory (a simulated dataset, a whole
      calibration run) run on one worker, so the fixture is made once, not once per worker;
    - the modules with end-to-end (slow) tests come first: the long tests start early and the short ones fill the
      end, instead of one long test running alone at the end. Modules stay whole, so without -n a module's
      fixtures are still made once.
    """
    for item in items:
        shared = sorted(shared_fixture_group(item))
        if shared:
            item.add_marker(pytest.mark.xdist_group(shared[0]))
    slow_modules = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in slow_modules)  # stable: each module's order kept


def shared_fixture_group(item):
    """The groups of the non-function-scoped fixtures the test uses that this directory defines (pytest's own,
    such as tmp_path_factory, are left out): a test module's fixture is that module's, a conftest's its name's."""
    info = getattr(item, "_fixtureinfo", None)
    for name, definitions in (info.name2fixturedefs.items() if info else ()):
        for definition in definitions:
            if definition.scope != "function" and definition.baseid:
                yield definition.baseid if definition.baseid.endswith(".py") else f"fixture:{name}"


@pytest.fixture(scope="session")
def mock_run(tmp_path_factory):
    """One whole calibration of the ideal mock (seed 5, default plan, as `naocal calibrate --backend mock --mock
    ideal --seed 5` runs it), shared: tests/test_agent_mock.py checks the run, tests/test_diagnostics_mock.py
    diagnoses its dataset. (mock, DIR, result, context, number of commands the calibration sent)."""
    from agent.calibrate import calibrate
    from agent.states import AgentSettings
    from backends.mock import MockBackend

    out = tmp_path_factory.mktemp("mock_calibration")
    mock = MockBackend(MOCK_RUN_SEED)
    try:
        result, ctx = calibrate(mock, out, AgentSettings(seed=0, progress_bar=False),
                                backend_label=f"mock {MOCK_RUN_SEED}", truth=mock.truth_dict())
        yield mock, out, result, ctx, len(mock.command_log)
    finally:
        mock.close()

