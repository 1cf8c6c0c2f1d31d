"""The web page's password, stored as an scrypt hash (hashlib, no dependency).

Format: `scrypt$N$r$p$SALT$HASH`, salt and hash in unpadded URL-safe base64. N = 2^14, r = 8
(16 MiB, about 0.1 s on a Raspberry Pi 3): slow enough that a stolen config file does not
give the password away cheaply, fast enough for a login. Kept free of the web server's
imports, so the config reader checks a hash without them.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os
import re
from typing import NamedTuple

SCRYPT_N = 1 << 14
SCRYPT_R = 8
SCRYPT_P = 1
SALT_BYTES = 16
HASH_BYTES = 32
_FORMAT = re.compile(
    r"scrypt\$(\d{1,7})\$(\d{1,2})\$(\d{1,2})\$([A-Za-z0-9_-]{16,})\$([A-Za-z0-9_-]{32,})"
)
EXAMPLE = "scrypt$16384$8$1$<salt>$<hash> (make one with `hermsd web --hash-password`)"


class PasswordHash(NamedTuple):
    n: int
    r: int
    p: int
    salt: bytes
    digest: bytes


def _b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).rstrip(b"=").decode()


def _unb64(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def _scrypt(password: str, salt: bytes, n: int, r: int, p: int, length: int) -> bytes:
    return hashlib.scrypt(
        password.encode(), salt=salt, n=n, r=r, p=p, maxmem=256 * n * r + (1 << 20), dklen=length
    )


def hash_password(password: str, salt: bytes | None = None) -> str:
    """The stored form of `password` (a fresh random salt unless one is given)."""
    salt = os.urandom(SALT_BYTES) if salt is None else salt
    digest = _scrypt(password, salt, SCRYPT_N, SCRYPT_R, SCRYPT_P, HASH_BYTES)
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


def parse_hash(text: str) -> PasswordHash | None:
    """The parts of a stored hash, or None when it is not one (or asks for absurd costs)."""
    match = _FORMAT.fullmatch(text)
    if match is None:
        return None
    n, r, p = (int(match.group(i)) for i in (1, 2, 3))
    if n < 2 or n & (n - 1) or n > 1 << 20 or not 1 <= r <= 32 or not 1 <= p <= 16:
        return None
    return PasswordHash(n, r, p, _unb64(match.group(4)), _unb64(match.group(5)))


def verify_password(password: str, stored: PasswordHash) -> bool:
    """Whether `password` is the one hashed (in constant time for the comparison)."""
    digest = _scrypt(password, stored.salt, stored.n, stored.r, stored.p, len(stored.digest))
    return hmac.compare_digest(digest, stored.digest)
