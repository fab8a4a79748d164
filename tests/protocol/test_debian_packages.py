"""The shared apt-get helper (protocol/debian_packages.py), with dpkg-query and apt-get stubbed:
what is missing, the caller's error class and messages, the added environment, the log lines."""

import subprocess

import pytest

from protocol import debian_packages


class CallerError(RuntimeError):
    pass


def _stub(monkeypatch, installed: set[str], apt_rc: int = 0) -> list:
    calls = []

    def run(cmd, **kwargs):
        calls.append((cmd, kwargs.get("env")))
        if cmd[0] == "dpkg-query":
            names = cmd[3:]
            out = "".join(
                f"{n} {'installed' if n in installed else 'not-installed'}\n" for n in names
            )
            return subprocess.CompletedProcess(cmd, 0, out, "")
        if apt_rc == 0 and cmd[4:6] == ["install", "-y"]:
            installed.update(cmd[7:])
        return subprocess.CompletedProcess(cmd, apt_rc, "", "E: one\nE: two\n")

    monkeypatch.setattr(debian_packages.shutil, "which", lambda name: f"/usr/bin/{name}")
    monkeypatch.setattr(debian_packages.subprocess, "run", run)
    return calls


def test_missing_packages_in_order(monkeypatch):
    _stub(monkeypatch, {"b"})
    assert debian_packages.missing_packages(("a", "b", "c")) == ["a", "c"]


def test_no_debian_host_raises_the_callers_error(monkeypatch):
    monkeypatch.setattr(debian_packages.shutil, "which", lambda name: None)
    with pytest.raises(CallerError, match="^no dpkg here$"):
        debian_packages.missing_packages(("a",), error=CallerError, no_dpkg="no dpkg here")


def test_not_root_says_what_to_run(monkeypatch):
    _stub(monkeypatch, set())
    monkeypatch.setattr(debian_packages.os, "geteuid", lambda: 1000)
    with pytest.raises(CallerError) as exc:
        debian_packages.ensure(("a", "b"), log=print, error=CallerError)
    assert str(exc.value) == (
        "Debian packages missing and not root to install them: a b"
        " (run: sudo apt-get install --no-install-recommends a b)"
    )


def test_installs_as_root_with_the_added_environment(monkeypatch):
    calls = _stub(monkeypatch, {"b"})
    monkeypatch.setattr(debian_packages.os, "geteuid", lambda: 0)
    lines: list[str] = []
    debian_packages.ensure(("a", "b"), log=lines.append, env={"INITRD": "No"})
    apt = [(cmd, env) for cmd, env in calls if cmd[0] == "apt-get"]
    assert [cmd[4:] for cmd, _ in apt] == [
        ["update"],
        ["install", "-y", "--no-install-recommends", "a"],
    ]
    assert all(
        env["INITRD"] == "No" and env["DEBIAN_FRONTEND"] == "noninteractive" for _, env in apt
    )
    assert lines[0] == "installing Debian packages: a"
    assert lines[1].startswith("installed Debian packages in ")


def test_apt_get_failure_quotes_its_last_lines(monkeypatch):
    _stub(monkeypatch, set(), apt_rc=100)
    monkeypatch.setattr(debian_packages.os, "geteuid", lambda: 0)
    with pytest.raises(
        CallerError, match=r"^apt-get update failed \(exit 100\): E: one \| E: two$"
    ):
        debian_packages.ensure(("a",), log=print, error=CallerError)
