// The API page (/docs): Swagger UI over the station's OpenAPI description, from files served by the station.
window.ui = SwaggerUIBundle({ url: "/openapi.json", dom_id: "#swagger-ui", deepLinking: true });
