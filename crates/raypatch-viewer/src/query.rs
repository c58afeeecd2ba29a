//! The parameters of `GET /render.png` and `GET /input.png`, checked against what was loaded: indices, never
//! paths; bounded sizes; poses. The query string is read here; sizes and poses are checked by
//! `raypatch::input`, whose refusals are answered with the status of their kind.

use glam::DMat4;

use crate::catalog::{opengl_pose, ModelEntry, SceneEntry, ViewOutput, MAX_PIXELS, MAX_SIDE};
use crate::http::HttpError;

/// The longest client id (the page's random id, which makes a client's newest camera replace its older one).
const MAX_CLIENT_ID: usize = 64;

/// One render asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderQuery {
    pub model: usize,
    pub scene: usize,
    pub output: ViewOutput,
    pub width: usize,
    pub height: usize,
    /// Camera-to-world, OpenGL axes.
    pub pose: DMat4,
    /// The page's id: a newer request with the same id replaces this one while it waits.
    pub client: Option<String>,
}

/// The value of each of `known` in `query`; any other parameter is an error.
fn parameters<'q, const N: usize>(
    query: &'q [(String, String)],
    known: [&str; N],
) -> Result<[Option<&'q str>; N], HttpError> {
    let mut values = [None; N];
    for (key, value) in query {
        let i = known.iter().position(|k| k == key).ok_or_else(|| {
            HttpError::bad(format!("parameter `{}`: unknown (expected {})", shorten(key), known.join(", ")))
        })?;
        values[i] = Some(value.as_str());
    }
    Ok(values)
}

/// Text from the request, cut short for a message.
fn shorten(text: &str) -> String {
    let mut short: String = text.chars().take(40).collect();
    if short.len() < text.len() {
        short.push('…');
    }
    short
}

/// `name=value` as an index below `count`.
fn index(name: &str, value: Option<&str>, count: usize, what: &str) -> Result<usize, HttpError> {
    let Some(value) = value else { return Ok(0) };
    match value.parse::<usize>() {
        Ok(i) if i < count => Ok(i),
        _ => Err(HttpError::bad(format!(
            "{name}: `{}` is not one of the {count} {what} loaded (expected an index, 0 to {})",
            shorten(value),
            count.saturating_sub(1)
        ))),
    }
}

pub fn parse_render(
    query: &[(String, String)],
    models: &[ModelEntry],
    scenes: &[SceneEntry],
) -> Result<RenderQuery, HttpError> {
    let [model, scene, output, size, pose, client] =
        parameters(query, ["model", "scene", "output", "size", "pose", "client"])?;
    let model = index("model", model, models.len(), "models")?;
    let scene = index("scene", scene, scenes.len(), "scenes")?;
    let entry = &models[model];
    let output = match output {
        None => ViewOutput::Rgb,
        Some(name) => {
            let known = entry.outputs.iter().map(|o| o.name()).collect::<Vec<_>>().join(", ");
            *entry.outputs.iter().find(|o| o.name() == name).ok_or_else(|| {
                HttpError::bad(format!(
                    "output: `{}` is not one model {model} renders (it renders {known})",
                    shorten(name)
                ))
            })?
        }
    };
    let reference = &scenes[scene].reference;
    let (width, height) = match size {
        None => scenes[scene].full_size(entry.sizes),
        Some(text) => parse_size(text, entry.sizes)?,
    };
    let pose = match pose {
        Some(text) => parse_pose(text)?,
        None => opengl_pose(reference)
            .ok_or_else(|| HttpError::bad("pose: required (this scene's cameras are given by rays, not poses)"))?,
    };
    let client = match client {
        Some(id)
            if (1..=MAX_CLIENT_ID).contains(&id.len())
                && id.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_') =>
        {
            Some(id.to_string())
        }
        Some(id) => {
            return Err(HttpError::bad(format!(
                "client: `{}` is not an id (expected 1 to {MAX_CLIENT_ID} letters, digits, - or _)",
                shorten(id)
            )))
        }
        None => None,
    };
    Ok(RenderQuery { model, scene, output, width, height, pose, client })
}

/// `WxH`: whole pixels, each side 1 to [`MAX_SIDE`], at most [`MAX_PIXELS`] in all, and a size the model
/// renders (`raypatch::input::check_patch_size`).
fn parse_size(text: &str, sizes: raypatch::PatchSize) -> Result<(usize, usize), HttpError> {
    let expected = format!("expected WxH, sides 1 to {MAX_SIDE}, at most {MAX_PIXELS} pixels");
    let bad = || HttpError::bad(format!("size: `{}`: {expected}", shorten(text)));
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let side = |s: &str| s.parse::<usize>().ok().filter(|v| (1..=MAX_SIDE).contains(v));
    let (w, h) = match (side(w), side(h)) {
        (Some(w), Some(h)) if w * h <= MAX_PIXELS => (w, h),
        _ => return Err(bad()),
    };
    raypatch::input::check_patch_size(sizes, w, h).map_err(|e| HttpError::of(&e).about("size"))?;
    Ok((w, h))
}

/// 16 numbers separated by commas (or spaces): a camera-to-world matrix, row by row, OpenGL axes (as NeRF's
/// transform_matrix); `raypatch::input::pose_from_numbers` checks them.
fn parse_pose(text: &str) -> Result<DMat4, HttpError> {
    let numbers = (text.split([',', ' ']).filter(|p| !p.is_empty()).take(17).enumerate())
        .map(|(i, part)| {
            part.parse::<f64>()
                .map_err(|_| HttpError::bad(format!("pose: number {i} is `{}`: expected a number", shorten(part))))
        })
        .collect::<Result<Vec<f64>, HttpError>>()?;
    raypatch::input::pose_from_numbers(&numbers).map_err(|e| HttpError::of(&e))
}

/// `GET /input.png?scene=S&view=I`: which input image.
pub fn parse_input(query: &[(String, String)], scenes: &[SceneEntry]) -> Result<(usize, usize), HttpError> {
    let [scene, view] = parameters(query, ["scene", "view"])?;
    let scene = index("scene", scene, scenes.len(), "scenes")?;
    let view = index("view", view, scenes[scene].thumbnails.len(), "input views of the scene")?;
    Ok((scene, view))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_poses_are_bounded() {
        let k4 = raypatch::PatchSize { k: 4, any_size: false };
        assert_eq!(parse_size("80x60", k4), Ok((80, 60)));
        for bad in ["81x60", "0x4", "4096x4", "1024x1024", "80", "x", "-4x4", "8x8x8", "1e3x4"] {
            assert_eq!(parse_size(bad, k4).unwrap_err().status, 400, "{bad}");
        }
        let identity = "1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1";
        assert_eq!(parse_pose(identity), Ok(DMat4::IDENTITY));
        let translated = parse_pose("1 0 0 5 0 1 0 6 0 0 1 7 0 0 0 1").unwrap();
        assert_eq!(translated.w_axis.truncate(), glam::DVec3::new(5.0, 6.0, 7.0));
        for bad in ["", "1,2,3", &format!("{identity},1"), &identity.replace("1,0,0,0,0", "NaN,0,0,0,0")] {
            let error = parse_pose(bad).unwrap_err();
            assert!(error.status == 400 && error.message.starts_with("pose: "), "{bad}: {error:?}");
        }
        assert!(parse_pose(&identity.replace('1', "inf")).is_err());
    }
}
