// The API docs page (/api/docs): the server's OpenAPI document drawn by
// the bundled Swagger UI. "Try it out" sends the browser's own cookie
// (signed in at /login), or a token given under "Authorize".
"use strict";
window.addEventListener("load", () => {
  window.ui = SwaggerUIBundle({
    url: "/api/v1/openapi.json",
    dom_id: "#api-docs",
    deepLinking: true,
    // No validator badge: it would call out to validator.swagger.io.
    validatorUrl: null,
    withCredentials: true,
  });
});
