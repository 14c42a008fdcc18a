"""The login page at ``/``: a plain form that posts to ``/api/v1/auth/login`` and goes on to
``/dashboard/``. Logged in already: who, a link to the dashboard and a logout button.
``/?logout=1`` (the dashboard's Log out button) ends the login with ``/api/v1/auth/logout``
first. No external resources, no inline event handlers other than this one script."""

from __future__ import annotations

import html

PAGE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>ergoseek · sign in</title>
<link rel="icon" href="data:,">
<style>
  body {{ font-family: system-ui, sans-serif; background: #f1f3f5; margin: 0; }}
  main {{ max-width: 360px; margin: 12vh auto; background: #fff; padding: 28px 32px;
         border-radius: 8px; box-shadow: 0 2px 12px rgba(0,0,0,.08); }}
  h1 {{ font-size: 1.4em; margin: 0 0 4px 0; }}
  p.sub {{ color: #666; margin: 0 0 20px 0; font-size: .9em; }}
  label {{ display: block; margin: 12px 0 4px 0; font-size: .9em; }}
  input {{ width: 100%; box-sizing: border-box; padding: 8px; font-size: 1em;
          border: 1px solid #ced4da; border-radius: 4px; }}
  button, a.button {{ display: inline-block; margin-top: 18px; padding: 9px 18px;
          font-size: 1em; border-radius: 4px; border: 0; background: #1c7ed6; color: #fff;
          text-decoration: none; cursor: pointer; }}
  button.secondary {{ background: #868e96; margin-left: 8px; }}
  #error {{ color: #c92a2a; min-height: 1.2em; margin-top: 12px; font-size: .9em; }}
  [hidden] {{ display: none !important; }}
</style>
</head>
<body>
<main>
  <h1>ergoseek</h1>
  <p class="sub">Extremum-seeking exercise machine · trainer dashboard</p>
  <section id="signed-in" {signed_in_hidden}>
    <p>Signed in as <strong id="who">{who}</strong>.</p>
    <a class="button" href="/dashboard/">Open the dashboard</a>
    <button type="button" class="secondary" id="logout">Log out</button>
  </section>
  <form id="login" {form_hidden}>
    <label for="login-name">Login</label>
    <input id="login-name" name="login" autocomplete="username" required autofocus>
    <label for="password">Password</label>
    <input id="password" name="password" type="password" autocomplete="current-password" required>
    <button type="submit">Sign in</button>
  </form>
  <div id="error" role="alert"></div>
</main>
<script>
(() => {{
  const form = document.getElementById("login");
  const signedIn = document.getElementById("signed-in");
  const error = document.getElementById("error");
  async function logout() {{
    try {{ await fetch("/api/v1/auth/logout", {{method: "POST", credentials: "same-origin"}}); }}
    catch (e) {{ /* offline: the cookie stays, the server still decides */ }}
    history.replaceState(null, "", "/");
    signedIn.hidden = true;
    form.hidden = false;
    error.textContent = "Logged out.";
  }}
  document.getElementById("logout").addEventListener("click", logout);
  form.addEventListener("submit", async (ev) => {{
    ev.preventDefault();
    error.textContent = "";
    const body = {{login: form.login.value, password: form.password.value}};
    let r;
    try {{
      r = await fetch("/api/v1/auth/login", {{
        method: "POST", credentials: "same-origin",
        headers: {{"Content-Type": "application/json"}}, body: JSON.stringify(body),
      }});
    }} catch (e) {{ error.textContent = "The server cannot be reached."; return; }}
    if (r.ok) {{ window.location.assign("/dashboard/"); return; }}
    let detail = "Sign-in failed (" + r.status + ").";
    if (r.status === 401) {{ detail = "Wrong login or password."; }}
    if (r.status === 429) {{ detail = "Too many failed logins: try again later."; }}
    error.textContent = detail;
  }});
  if (new URLSearchParams(location.search).has("logout")) {{ logout(); }}
}})();
</script>
</body>
</html>
"""


def render(who: str | None) -> str:
    return PAGE.format(
        who=html.escape(who or ""),
        signed_in_hidden="" if who else "hidden",
        form_hidden="hidden" if who else "",
    )
