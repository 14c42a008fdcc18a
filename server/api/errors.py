"""How the API reports what went wrong: 422 naming the field and the reason (the body's own
validation, the store's and the session policy's), 404 for an unknown id, 409 when the machine
or the store refuses for now (a session running, a latch, the worker lost)."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from server.service import BusyError
from sessions.requests import RequestError
from sessions.store import ConflictError, NotFoundError, StoreValueError
from sessions.worker import WorkerError


def problem(status: int, detail: Any) -> JSONResponse:
    return JSONResponse(status_code=status, content={"detail": detail})


def field_problem(field: str, reason: str, where: str = "body") -> JSONResponse:
    """422 for one field (dotted path) of the body, the query or the path."""
    loc = [where, *field.split(".")]
    return problem(422, [{"loc": loc, "msg": reason, "type": "value_error"}])


def _where(request: Request, field: str) -> str:
    """Whether ``field`` is one of the route's query or path parameters (else the body's)."""
    head = field.split(".", 1)[0]
    todo = [getattr(request.scope.get("route"), "dependant", None)]
    while todo:  # the route's own parameters and its dependencies'
        dependant = todo.pop()
        if dependant is None:
            continue
        if head in {p.alias for p in dependant.query_params}:
            return "query"
        if head in {p.alias for p in dependant.path_params}:
            return "path"
        todo.extend(dependant.dependencies)
    return "body"


async def _store_value(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StoreValueError | RequestError)
    return field_problem(exc.field, exc.reason, _where(request, exc.field))


async def _not_found(_: Request, exc: Exception) -> JSONResponse:
    return problem(404, str(exc))


async def _conflict(_: Request, exc: Exception) -> JSONResponse:
    return problem(409, str(exc))


async def _validation(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    detail = [
        {"loc": list(e["loc"]), "msg": e["msg"].removeprefix("Value error, "), "type": e["type"]}
        for e in exc.errors()
    ]
    return problem(422, detail)


def install(app: FastAPI) -> None:
    """The exception handlers, on ``app``."""
    app.add_exception_handler(StoreValueError, _store_value)
    app.add_exception_handler(RequestError, _store_value)
    app.add_exception_handler(NotFoundError, _not_found)
    for conflict in (ConflictError, BusyError, WorkerError):  # running, latched, worker down
        app.add_exception_handler(conflict, _conflict)
    app.add_exception_handler(RequestValidationError, _validation)
