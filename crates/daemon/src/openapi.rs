//! The API's OpenAPI description, served at `GET /api/v1/openapi.json`. It is generated from
//! the handlers' `#[utoipa::path]` attributes as [`super::api::router`] registers them
//! (utoipa-axum), so a route cannot exist without its description, nor the other way round.
//! What the middleware adds to every answer (401, 421, 429, 415) is added here to every
//! operation by [`Guards`], the one place that mirrors it; it also gives every error its
//! media type, `application/problem+json`.

pub use brdfd_api::answers::*;
use utoipa::openapi::header::HeaderBuilder;
use utoipa::openapi::path::Operation;
use utoipa::openapi::schema::{ObjectBuilder, Type};
use utoipa::openapi::security::{
    ApiKey, ApiKeyValue, HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme,
};
use utoipa::openapi::{ContentBuilder, OpenApi, Ref, RefOr, ResponseBuilder};
use utoipa::{Modify, ToSchema};

/// One server-sent event of a session's stream (the fields of the `text/event-stream`
/// format).
#[derive(ToSchema)]
pub struct StreamEvent {
    /// `<run>-<place>`: given back as `Last-Event-ID`, the stream resumes after it.
    pub id: String,
    /// The event type; brdfd sends none (`message`), the type is in `data`.
    pub event: Option<String>,
    /// An `Event` (see the schema of that name) as JSON.
    pub data: String,
}

/// A file's bytes, as stored.
#[derive(ToSchema)]
#[schema(value_type = String, format = Binary)]
pub struct FileBytes(pub Vec<u8>);

#[derive(utoipa::OpenApi)]
#[openapi(
    info(
        title = "brdfd",
        version = env!("CARGO_PKG_VERSION"),
        description = "The brdfd daemon's HTTP API (`brdfd serve`): devices, captures and their \
                       results. docs/api.md says more.",
        license(name = "MIT", identifier = "MIT"),
    ),
    components(schemas(ErrorBody, brdfd_rig::Event, super::api::ResultFile, super::api::MaterialFolder))
)]
pub struct ApiDoc;

/// Adds what the middleware answers to every operation: 401 (a daemon with a token), 429
/// (an address locked out for wrong tokens), 421 (a `Host` not its own), 415 on a POST
/// without a JSON body; the two ways to give the token; and `application/problem+json` as
/// every error's media type. Applied to the whole description once the routes are in it.
pub struct Guards;

impl Modify for Guards {
    fn modify(&self, api: &mut OpenApi) {
        let components = api.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "token",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
        components.add_security_scheme(
            "signed_in",
            SecurityScheme::ApiKey(ApiKey::Cookie(ApiKeyValue::new(super::web::COOKIE))),
        );
        // With a token configured, one of the two is needed; without, neither (`{}`).
        api.security = Some(vec![
            SecurityRequirement::new("token", Vec::<String>::new()),
            SecurityRequirement::new("signed_in", Vec::<String>::new()),
            SecurityRequirement::default(),
        ]);
        let error = |what: &str, header: Option<(&str, &str)>| {
            let mut response = ResponseBuilder::new().description(what).content(
                PROBLEM,
                ContentBuilder::new()
                    .schema(Some(Ref::from_schema_name("ErrorBody")))
                    .build(),
            );
            if let Some((name, says)) = header {
                let header = HeaderBuilder::new()
                    .schema(Some(ObjectBuilder::new().schema_type(Type::String)))
                    .description(Some(says))
                    .build();
                response = response.header(name, header);
            }
            response.build()
        };
        let add = |op: &mut Operation, status: &str, what: &str, header| {
            op.responses
                .responses
                .entry(status.to_string())
                .or_insert_with(|| error(what, header).into());
        };
        for item in api.paths.paths.values_mut() {
            let ops = [
                item.get.as_mut(),
                item.post.as_mut(),
                item.put.as_mut(),
                item.delete.as_mut(),
                item.patch.as_mut(),
            ];
            for (op, post) in ops
                .into_iter()
                .zip([false, true, false, false, false])
                .filter_map(|(op, post)| op.map(|op| (op, post)))
            {
                add(
                    op,
                    "401",
                    "`unauthorized`: the daemon has a token and none was given",
                    Some((
                        "WWW-Authenticate",
                        "`Bearer realm=\"brdfd\"` (RFC 9110 §11.6.1)",
                    )),
                );
                add(
                    op,
                    "429",
                    "`too_many_attempts`: this address gave wrong tokens, and must wait",
                    Some(("Retry-After", "seconds to wait")),
                );
                add(
                    op,
                    "421",
                    "`unknown_host`: the request's `Host` is not this daemon's",
                    None,
                );
                if post {
                    add(
                        op,
                        "415",
                        "`unsupported_media_type`: a POST without `Content-Type: application/json`",
                        None,
                    );
                }
                problems(op);
            }
        }
    }
}

/// Every answer of `op` whose body is an [`ErrorBody`] as [`PROBLEM`]: the handlers' own
/// errors are declared with `body = ErrorBody`, which utoipa gives `application/json`.
fn problems(op: &mut Operation) {
    for response in op.responses.responses.values_mut() {
        let RefOr::T(response) = response else {
            continue;
        };
        let is_problem = match response.content.get("application/json") {
            Some(RefOr::T(c)) => {
                matches!(&c.schema, Some(RefOr::Ref(r)) if r.ref_location.ends_with("/ErrorBody"))
            }
            _ => false,
        };
        if is_problem {
            if let Some(content) = response.content.shift_remove("application/json") {
                response.content.insert(PROBLEM.to_string(), content);
            }
        }
    }
}
