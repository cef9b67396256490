"""Settings: QEM_* variables, safe defaults, refused unsafe values."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from server.settings import Settings, get_settings

TOKEN = "t" * 16


def test_defaults(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    settings = Settings(_env_file=None)
    assert settings.data_dir == tmp_path / "data"
    assert settings.tokens == () and not settings.auth_enabled
    assert settings.workers >= 1
    assert (settings.metadata_backend, settings.blob_backend, settings.jobs_backend) == (
        "sqlite",
        "local",
        "local",
    )


def test_environment_variables(tmp_path, monkeypatch):
    monkeypatch.setenv("QEM_DATA_DIR", str(tmp_path / "d"))
    monkeypatch.setenv("QEM_TOKENS", f"{TOKEN}, {'u' * 20}")
    monkeypatch.setenv("QEM_MAX_UPLOAD_BYTES", "1000")
    monkeypatch.setenv("QEM_WORKERS", "3")
    settings = Settings(_env_file=None)
    assert settings.data_dir == tmp_path / "d"
    assert settings.tokens == (TOKEN, "u" * 20) and settings.auth_enabled
    assert (settings.max_upload_bytes, settings.workers) == (1000, 3)


def test_tokens_are_not_shown(tmp_path):
    assert TOKEN not in repr(Settings(data_dir=tmp_path, tokens=TOKEN, _env_file=None))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("tokens", "short", "at least 16"),
        ("tokens", "has a space inside it", "whitespace"),
        ("max_upload_bytes", 0, "greater than or equal to 1"),
        ("workers", 0, "greater than or equal to 1"),
        ("workers", 1000, "less than or equal to 64"),
        ("data_dir", "/", "filesystem root"),
        ("metadata_backend", "postgres", "is not one of ['postgresql', 'sqlite']"),
        ("blob_backend", "gcs", "is not one of ['local', 's3']"),
        ("jobs_backend", "redis", "is not one of ['local', 'postgresql']"),
        ("database_url", "mysql://db/qem", "QEM_DATABASE_URL must be postgresql://"),
        ("blob_url", "https://bucket.example/x", "a blob URL is s3://bucket/prefix"),
        ("blob_url", "s3:///prefix", "a blob URL is s3://bucket/prefix"),
        ("demo_mesh", "/no/such/file.obj", "is not a file"),
        ("progress_interval_s", 0, "greater than 0"),
        ("max_build_seconds", 0, "greater than 0"),
        ("max_build_seconds", float("nan"), "finite number"),
        ("progress_interval_s", float("nan"), "finite number"),
    ],
)
def test_unsafe_values_are_refused(tmp_path, field, value, message):
    values = {"data_dir": tmp_path, field: value}
    with pytest.raises(ValidationError, match=message.replace("[", r"\[")):
        Settings(**values, _env_file=None)


def test_data_dir_must_be_a_directory(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValidationError, match="not a directory"):
        Settings(data_dir=tmp_path / "file", _env_file=None)


def test_get_settings_is_cached(monkeypatch, tmp_path):
    monkeypatch.setenv("QEM_DATA_DIR", str(tmp_path))
    get_settings.cache_clear()
    try:
        assert get_settings() is get_settings()
        assert get_settings().data_dir == tmp_path
    finally:
        get_settings.cache_clear()
