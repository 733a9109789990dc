"""aquarium_warp.records.git_info: where a result file's commit comes from."""

from aquarium_warp.records import git_info


def test_given_commit_overrides_git(monkeypatch):
    monkeypatch.delenv("AQUARIUM_WARP_COMMIT", raising=False)
    assert git_info("abc1234") == {"commit": "abc1234", "dirty": None, "source": "given"}


def test_environment_names_the_commit_of_a_copy_without_git(monkeypatch):
    monkeypatch.setenv("AQUARIUM_WARP_COMMIT", "def5678")
    assert git_info() == {"commit": "def5678", "dirty": None, "source": "given"}
    assert git_info("abc1234")["commit"] == "abc1234"  # an explicit commit wins


def test_without_override_the_checkout_is_read(monkeypatch):
    monkeypatch.delenv("AQUARIUM_WARP_COMMIT", raising=False)
    info = git_info()
    assert info["source"] in ("git", "git failed", "no git")
    if info["source"] == "git":
        assert len(info["commit"]) == 40
