"""Logging in and out: a browser cookie or a bearer token, and who am I."""

from __future__ import annotations

import asyncio
from datetime import timedelta

from fastapi import APIRouter, HTTPException, Request, Response, status

from server.auth import COOKIE, LoginLimiter, Viewer, client_keys, identify, retry_after_header
from server.schemas import LoginIn, Me, TokenOut
from sessions.store import AccountRecord

router = APIRouter(prefix="/api/v1/auth", tags=["auth"])


async def _authenticate(request: Request, body: LoginIn) -> AccountRecord:
    runtime = request.app.state.runtime
    limiter: LoginLimiter = runtime.limiter
    keys = client_keys(request, body.login)
    wait = limiter.retry_after(keys)
    if wait > 0:
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            detail="too many failed logins: try again later",
            headers=retry_after_header(wait),
        )
    account = await asyncio.to_thread(
        runtime.store.accounts.authenticate, body.login, body.password
    )
    if account is None:
        limiter.failed(keys)
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, detail="wrong login name or password")
    limiter.succeeded(keys)
    return account


@router.post("/login", response_model=Me, summary="Log in a browser (sets an HttpOnly cookie)")
async def login(request: Request, body: LoginIn, response: Response) -> Me:
    account = await _authenticate(request, body)
    runtime = request.app.state.runtime
    lifetime = timedelta(hours=runtime.settings.session_hours)
    token, _ = await asyncio.to_thread(runtime.store.tokens.issue, account.id, "cookie", lifetime)
    response.set_cookie(
        COOKIE,
        token,
        max_age=int(lifetime.total_seconds()),
        httponly=True,
        samesite="strict",
        secure=runtime.settings.cookie_secure,
        path="/",
    )
    return Me(account=account, via="cookie")


@router.post("/token", response_model=TokenOut, summary="Get a bearer token for an API client")
async def token(request: Request, body: LoginIn) -> TokenOut:
    account = await _authenticate(request, body)
    runtime = request.app.state.runtime
    lifetime = timedelta(hours=runtime.settings.session_hours)
    secret, record = await asyncio.to_thread(
        runtime.store.tokens.issue, account.id, "bearer", lifetime
    )
    return TokenOut(access_token=secret, expires_at=record.expires_at)


@router.post("/logout", status_code=204, summary="End this login (cookie or bearer token)")
async def logout(request: Request, response: Response, _: Viewer) -> Response:
    runtime = request.app.state.runtime
    from server.auth import bearer

    secret = bearer(request) or request.cookies.get(COOKIE)
    if secret:
        await asyncio.to_thread(runtime.store.tokens.revoke, secret)
    response = Response(status_code=204)
    response.delete_cookie(COOKIE, path="/")
    return response


@router.get("/me", response_model=Me, summary="Who is logged in")
async def me(request: Request, account: Viewer) -> Me:
    _, how = await asyncio.to_thread(identify, request, request.app.state.runtime.store)
    return Me(account=account, via="bearer" if how == "bearer" else "cookie")
