"""The HTTP kit that the site's console and the control room share: the server (uvicorn in a
thread, its connection limits), the allowed hosts, the request limits and headers, the error
answers that name no file, the accounts (users) and their sessions (auth), and the login
routes (login). Nothing in it knows a site or a control room."""
