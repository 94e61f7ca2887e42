#version 330
// Element ids into an atlas of cube maps (core/visibility/id_cubes.py): each draw command of a
// multi-draw draws one element into one cube face of one sample point, whose eye and tile
// (column: the face, row: the point in its batch) come from the per-instance attributes at the
// command's base instance.  The face's 90-degree frustum is cut by four clip distances (the GL
// enables them) before the clip position moves into its tile, so one call fills a batch's atlas.
uniform mat3 face_frames[6];  // rows: right, up, forward of each face (world -> face eye frame)
uniform vec2 depth_range;     // near, far
uniform vec2 tiles;           // atlas columns (6), rows (points in the batch)
uniform float guard;          // a face spans -guard..guard in tan (1: 90 degrees; more: a guard band)
in vec3 in_position;          // relative to the scene's origin (float64-built)
in uint in_id;                // element index + 1
in vec3 in_eye;               // per instance: the sample point, relative to the same origin
in vec2 in_tile;              // per instance: face (0..5), row
flat out uint v_id;
out float gl_ClipDistance[4];
void main() {
    int face = int(in_tile.x);
    float row = in_tile.y;
    vec3 e = face_frames[face] * (in_position - in_eye);  // x right, y up, z forward
    e.xy /= guard;
    float n = depth_range.x, f = depth_range.y;
    vec4 clip = vec4(e.x, e.y, (f + n) / (f - n) * e.z - 2.0 * f * n / (f - n), e.z);
    gl_ClipDistance[0] = clip.w + clip.x;
    gl_ClipDistance[1] = clip.w - clip.x;
    gl_ClipDistance[2] = clip.w + clip.y;
    gl_ClipDistance[3] = clip.w - clip.y;
    float w = clip.w;
    gl_Position = vec4(-w + (2.0 * float(face) * w + clip.x + w) / tiles.x,
                       -w + (2.0 * row * w + clip.y + w) / tiles.y, clip.z, w);
    v_id = in_id;
}
