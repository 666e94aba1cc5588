"""The owner lock is taken on the resolved database file: every path to one database (a symlink,
``dir/../dir/x.db``, a symlinked folder) contends for one lock, so two campaign processes never own
one campaign."""

from __future__ import annotations

import subprocess
import sys

import pytest

from helicalib.errors import ConfigError
from helicalib.store import Store


@pytest.fixture
def owned(tmp_path):
    real = tmp_path / "data" / "x.db"
    Store.open(real).close()
    store = Store.open(real, owner="run field.yaml")
    yield real
    store.close()


def _paths(real):
    link_file = real.parent.parent / "link.db"
    link_file.symlink_to(real)
    link_dir = real.parent.parent / "linkdir"
    link_dir.symlink_to(real.parent, target_is_directory=True)
    return [link_file, real.parent / ".." / real.parent.name / real.name, link_dir / real.name]


def test_a_second_owner_through_another_path_is_refused_in_one_line(owned):
    for other in _paths(owned):
        with pytest.raises(ConfigError) as err:
            Store.open(other, owner="run other.yaml")
        message = str(err.value)
        assert "in use by helicalib" in message and "run field.yaml" in message and "\n" not in message, other


def test_the_lock_sits_beside_the_real_file_and_readers_name_the_owner(owned):
    link = _paths(owned)[0]
    with Store.open(link, readonly=True) as reader:
        assert reader.lock_path == owned.with_name("x.db.lock")
        assert "run field.yaml" in (reader.owner() or "")
    assert not link.with_name("link.db.lock").exists()


def test_a_second_process_through_a_symlink_is_refused(owned):
    """Two processes, as two ``run --arm`` would be: the second, given the symlink, exits with one line."""
    link = _paths(owned)[0]
    code = ("import sys\nfrom helicalib.store import Store\nfrom helicalib.errors import HelicalibError\n"
            "try:\n    Store.open(sys.argv[1], owner='run second')\nexcept HelicalibError as e:\n"
            "    print(e, file=sys.stderr); sys.exit(1)\n")
    second = subprocess.run([sys.executable, "-c", code, str(link)], capture_output=True, text=True, timeout=60)
    assert second.returncode == 1 and "in use by helicalib" in second.stderr, second.stderr
    assert len(second.stderr.strip().splitlines()) == 1
