"""Logging in and out: a browser cookie or a bearer token, and who am I."""

from __future__ import annotations

import asyncio
from datetime import timedelta

from fastapi import APIRouter, HTTPException, Request, Response, status

from server.api.deps import LimiterDep, RuntimeDep, SettingsDep, StoreDep, Viewer
from server.api.schemas import LoginIn, Me, TokenOut
from server.security import (
    COOKIE,
    DEVICE_COOKIE,
    DEVICE_COOKIE_DAYS,
    LoginLimiter,
    bearer,
    identify,
    retry_after_header,
)
from sessions.store import AccountRecord, Store, TokenRecord

router = APIRouter(prefix="/api/v1/auth", tags=["auth"])


HASHING_QUEUE = 16  # waiting beyond that: 503 at once, nothing hashed


async def _authenticate(
    request: Request, response: Response, body: LoginIn, store: Store, limiter: LoginLimiter
) -> AccountRecord:
    keys = limiter.keys(request, body.login)
    wait = limiter.retry_after(keys)
    if wait > 0:
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            detail="too many failed logins: try again later",
            headers=retry_after_header(wait),
        )
    account = await _check_password(store, limiter, body)
    if account is None:
        limiter.failed(keys)
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, detail="wrong login name or password")
    limiter.succeeded(keys)
    response.set_cookie(  # this browser is known-good for this login from now on
        DEVICE_COOKIE,
        limiter.device_cookie(account.login),
        max_age=DEVICE_COOKIE_DAYS * 86400,
        httponly=True,
        samesite="strict",
        secure=request.app.state.settings.cookie_secure,
        path="/api/v1/auth",
    )
    return account


async def _check_password(
    store: Store, limiter: LoginLimiter, body: LoginIn
) -> AccountRecord | None:
    """The store's password check, a few at a time: a burst of logins queues (bounded) rather
    than taking every core and all the memory."""
    if limiter.hashing_waiting >= HASHING_QUEUE:
        raise HTTPException(
            status.HTTP_503_SERVICE_UNAVAILABLE,
            detail="too many logins at once: try again",
            headers=retry_after_header(1),
        )
    limiter.hashing_waiting += 1
    try:
        await limiter.hashing.acquire()
    finally:
        limiter.hashing_waiting -= 1
    try:
        return await asyncio.to_thread(store.accounts.authenticate, body.login, body.password)
    finally:
        limiter.hashing.release()


def _issue(
    store: Store, account_id: int, kind: str, lifetime: timedelta
) -> tuple[str, TokenRecord]:
    """A new login; expired and revoked ones are forgotten at the same time."""
    store.tokens.purge()
    return store.tokens.issue(account_id, kind, lifetime)


@router.post("/login", response_model=Me, summary="Log in a browser (sets an HttpOnly cookie)")
async def login(
    request: Request,
    body: LoginIn,
    response: Response,
    store: StoreDep,
    limiter: LimiterDep,
    settings: SettingsDep,
    runtime: RuntimeDep,
) -> Me:
    account = await _authenticate(request, response, body, store, limiter)
    lifetime = timedelta(hours=settings.session_hours)
    token, _ = await asyncio.to_thread(_issue, store, account.id, "cookie", lifetime)
    runtime.accounts.changed(account.id, "login")
    response.set_cookie(
        COOKIE,
        token,
        max_age=int(lifetime.total_seconds()),
        httponly=True,
        samesite="strict",
        secure=settings.cookie_secure,
        path="/",
    )
    return Me(account=account, via="cookie")


@router.post("/token", response_model=TokenOut, summary="Get a bearer token for an API client")
async def token(
    request: Request,
    body: LoginIn,
    response: Response,
    store: StoreDep,
    limiter: LimiterDep,
    settings: SettingsDep,
    runtime: RuntimeDep,
) -> TokenOut:
    account = await _authenticate(request, response, body, store, limiter)
    lifetime = timedelta(hours=settings.session_hours)
    secret, record = await asyncio.to_thread(_issue, store, account.id, "bearer", lifetime)
    runtime.accounts.changed(account.id, "login")
    return TokenOut(access_token=secret, expires_at=record.expires_at)


@router.post("/logout", status_code=204, summary="End this login (cookie or bearer token)")
async def logout(
    request: Request, store: StoreDep, settings: SettingsDep, runtime: RuntimeDep, account: Viewer
) -> Response:
    secret = bearer(request) or request.cookies.get(COOKIE)
    if secret:
        await asyncio.to_thread(store.tokens.revoke, secret)
        runtime.accounts.changed(account.id, "logout")  # its connections close now
    response = Response(status_code=204)
    # deleted with the attributes it was set with (a browser matches on them)
    response.delete_cookie(
        COOKIE, path="/", httponly=True, samesite="strict", secure=settings.cookie_secure
    )
    return response


@router.get("/me", response_model=Me, summary="Who is logged in")
async def me(request: Request, store: StoreDep, account: Viewer) -> Me:
    _, how = await asyncio.to_thread(identify, request, store)
    return Me(account=account, via="bearer" if how == "bearer" else "cookie")
