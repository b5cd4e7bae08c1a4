"""Shared by every test folder. With pytest's default (prepend) import mode this file's folder, tests/, is put
on sys.path, so that fakes used in more than one folder live once: ``from fake_zenoh import FakeSample``."""
