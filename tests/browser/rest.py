"""The browser tests' own requests to the server under test (setting up, reading back).

httpx gives up after 5 s by default. With the whole suite on two cores, a sign-in (its
password hash) behind a page drawing WebGL in software took longer, and a test failed on
a server that had answered correctly. These wait as long as the pages' own actions can.
"""

import functools

import httpx

TIMEOUT_S = 60.0

get = functools.partial(httpx.get, timeout=TIMEOUT_S)
post = functools.partial(httpx.post, timeout=TIMEOUT_S)
patch = functools.partial(httpx.patch, timeout=TIMEOUT_S)


def signed_in(client: httpx.Client, creds: dict[str, str], login: str) -> httpx.Client:
    """``client`` signed in as the demo therapist (``creds``, :func:`server.cli.provision_demo`)
    by ``login``, the sign-in route as the client's base address reaches it."""
    r = client.post(
        login,
        json={"email": creds["therapist_email"], "password": creds["therapist_password"]},
    )
    assert r.status_code == 200, r.text
    client.headers["Authorization"] = f"Bearer {r.json()['access_token']}"
    return client
