"""The client over a real service: a fit of two routes, and reproductions that say theirs."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from canal_client import AsyncCanalClient, CanalClient
from canal_client.errors import CanalClientError
from canal_live import LiveService
from canal_testing import ROUTE_STARTS, two_route_demo


def test_fit_routes_and_reproduce_say_the_route(client: CanalClient,
                                                unique_name: Callable[[str], str]) -> None:
    name = unique_name("routes")
    client.create_skill(name, dim=3)
    for j in range(8):
        client.add_demo(name, two_route_demo(j))
    model = client.fit(name, n_samples=50)
    assert model.routes == 2 and model.demo_routes == [0] * 4 + [1] * 4
    for k, start in enumerate(ROUTE_STARTS):
        r = client.reproduce(name, start)
        assert (r.route, r.route_reason) == (k, "entry")
    forced = client.reproduce(name, ROUTE_STARTS[0], route=1)
    assert (forced.route, forced.route_reason) == (1, "forced")
    assert [r.route for r in client.reproduce_many(name, list(ROUTE_STARTS))] == [0, 1]
    with pytest.raises(CanalClientError, match="route"):
        client.reproduce(name, ROUTE_STARTS[0], route=4)
    routes = client.get_routes(name)
    assert routes.n_routes == 2 and routes.choose(np.array(ROUTE_STARTS[1])).route == 1
    np.testing.assert_allclose(client.get_canal(name).directrix, routes.pooled.directrix)
    single = client.fit(name, n_samples=50, routes=1)
    assert single.routes == 1 and single.demo_routes is None
    r = client.reproduce(name, ROUTE_STARTS[0])
    assert (r.route, r.route_reason) == (None, "single")


def test_the_async_client_sends_routes_too(service: LiveService,
                                           unique_name: Callable[[str], str]) -> None:
    import asyncio

    async def main() -> None:
        name = unique_name("aroutes")
        async with AsyncCanalClient(service.url) as c:
            await c.create_skill(name, dim=3)
            for j in range(8):
                await c.add_demo(name, two_route_demo(j))
            model = await c.fit(name, n_samples=40, routes=2)
            assert model.routes == 2
            r = await c.reproduce(name, ROUTE_STARTS[1])
            assert r.route == 1

    asyncio.run(main())
