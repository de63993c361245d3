"""Service settings: read from the environment, fail fast with the variable's name."""

from __future__ import annotations

import pytest

from bentray.service.settings import Settings, SettingsError, check_bind_host, owner_of_key


def test_defaults_and_values_from_env(tmp_path):
    keys = tmp_path / "keys.txt"
    keys.write_text("# team keys\nkey-from-file-0123456789\n\n")
    env = {
        "BENTRAY_API_KEYS": "first-key-0123456789, second-key-0123456789",
        "BENTRAY_API_KEYS_FILE": str(keys),
        "BENTRAY_DATA_DIR": str(tmp_path / "d"),
        "BENTRAY_MAX_RAYS": "1000",
        "BENTRAY_MAX_QUEUE": "3",
        "BENTRAY_MAX_JOB_SECONDS": "2.5",
        "BENTRAY_RETENTION_DAYS": "0.5",
        "BENTRAY_WORKERS": "0",
    }
    s = Settings.from_env(env)
    assert s.api_keys == ("first-key-0123456789", "second-key-0123456789", "key-from-file-0123456789")
    assert (s.max_rays, s.max_queue, s.max_job_seconds, s.retention_days, s.workers) == (1000, 3, 2.5, 0.5, 0)
    assert s.data_dir == tmp_path / "d" and s.db_path == tmp_path / "d" / "jobs.sqlite3"
    assert set(s.owners) == {owner_of_key(k) for k in s.api_keys} and len(owner_of_key("x")) == 32
    assert Settings.from_env({}, workers=4).workers == 4  # CLI flags win
    assert Settings.from_env({}).api_keys == ()


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"BENTRAY_MAX_RAYS": "-1"}, "BENTRAY_MAX_RAYS: Input should be greater than or equal to 1"),
        ({"BENTRAY_MAX_UPLOAD_BYTES": "lots"}, "BENTRAY_MAX_UPLOAD_BYTES: Input should be a valid integer"),
        ({"BENTRAY_MAX_JOB_SECONDS": "0"}, "BENTRAY_MAX_JOB_SECONDS: Input should be greater than 0"),
        ({"BENTRAY_API_KEYS": "short"}, "BENTRAY_API_KEYS: Value error, API key 1 must be at least 16 characters"),
        ({"BENTRAY_API_KEYS_FILE": "/nonexistent/keys"}, "BENTRAY_API_KEYS_FILE: cannot read /nonexistent/keys"),
    ],
)
def test_bad_values_fail_fast_naming_the_variable(env, message):
    with pytest.raises(SettingsError) as exc:
        Settings.from_env(env)
    assert message in str(exc.value)


def test_single_local_user_binds_loopback_only():
    local = Settings()
    for host in ("127.0.0.1", "::1", "localhost"):
        check_bind_host(local, host)
    for host in ("0.0.0.0", "192.168.1.10", "example.org"):
        with pytest.raises(SettingsError, match="binds 127.0.0.1 only"):
            check_bind_host(local, host)
    check_bind_host(Settings(api_keys=("k" * 20,)), "0.0.0.0")
