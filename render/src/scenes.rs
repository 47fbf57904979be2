//! The built-in scenes, made in code.

use crate::material::Material;
use crate::medium::Medium;
use crate::scene::{Camera, Scene, SceneBuilder};
use glam::Vec3;

/// A built-in scene: its name on the command line, how it is made, and whether it has a
/// stored reference at the default resolution, so that `--scene all` compares it.
#[derive(Clone, Copy, Debug)]
pub struct BuiltIn {
    /// The scene's name.
    pub name: &'static str,
    /// Makes the scene.
    pub make: fn() -> Scene,
    /// Whether `--scene all` renders it.
    pub compared: bool,
}

/// Every built-in scene, in the order reports list them.
pub const BUILT_IN: [BuiltIn; 8] = [
    BuiltIn {
        name: "door",
        make: door,
        compared: true,
    },
    BuiltIn {
        name: "glossy-box",
        make: glossy_box,
        compared: true,
    },
    BuiltIn {
        name: "uplight",
        make: uplight,
        compared: true,
    },
    BuiltIn {
        name: "covered",
        make: covered,
        compared: true,
    },
    BuiltIn {
        name: "caustic",
        make: caustic,
        compared: true,
    },
    BuiltIn {
        name: "furnace",
        make: || furnace(0.5, 1.0),
        compared: false,
    },
    BuiltIn {
        name: "fog",
        make: fog,
        compared: true,
    },
    BuiltIn {
        name: "medium-furnace",
        make: || medium_furnace(0.3, 1.0),
        compared: false,
    },
];

/// The built-in scene called `name`.
pub fn by_name(name: &str) -> Option<Scene> {
    BUILT_IN.iter().find(|s| s.name == name).map(|s| (s.make)())
}

/// The names of the scenes `--scene all` renders.
pub fn compared() -> impl Iterator<Item = &'static str> {
    BUILT_IN.iter().filter(|s| s.compared).map(|s| s.name)
}

/// The off-white walls of the `door` and `uplight` rooms.
fn room_wall() -> Material {
    Material::diffuse(Vec3::new(0.72, 0.70, 0.66))
}

/// The glossy wooden floor of the `door` and `uplight` rooms.
fn glossy_floor() -> Material {
    Material::glossy(Vec3::new(0.30, 0.22, 0.16), Vec3::splat(0.35), 0.12)
}

/// Registers the materials of the furniture both rooms hold, in this order (a scene's
/// fingerprint covers it): a metal sphere, a red box, a glossy blue sphere.
fn furniture_materials(b: &mut SceneBuilder) -> [u16; 3] {
    [
        Material::glossy(Vec3::splat(0.02), Vec3::new(0.90, 0.78, 0.55), 0.18),
        Material::diffuse(Vec3::new(0.62, 0.12, 0.10)),
        Material::glossy(Vec3::new(0.08, 0.14, 0.45), Vec3::splat(0.2), 0.3),
    ]
    .map(|m| b.material(m))
}

/// "Door ajar": a room lit only through a door left ajar to a second room, where a ceiling light
/// shines. Most of the camera room sees the light only after two or more bounces through the
/// gap, which unguided path tracing finds by chance; the floor is glossy.
///
/// Camera room `x ∈ [0, 4]`, light room `x ∈ [4, 7]`, `y ∈ [0, 2.5]`, `z ∈ [0, 5]`, metres. The
/// doorway is `z ∈ [2, 3]`, 2.1 m high; the door is hinged at `z = 2` and opened 12° into the
/// light room.
pub fn door() -> Scene {
    let (b, camera) = door_rooms();
    b.build("door", camera, 1.0)
}

/// "Fog": the rooms of [`door`] with the camera room filled with haze (extinction 0.25 per
/// metre, albedo 0.9, forward scattering with g = 0.6), lit only through the door ajar. The
/// light room is clear. The haze carries most of what the camera sees: the shaft of light
/// through the doorway scatters into the room, and light reaches the walls and furniture mostly
/// after scattering in the air. Next-event estimation from the haze finds the lamp only
/// through the gap.
pub fn fog() -> Scene {
    let (mut b, camera) = door_rooms();
    let haze = Medium {
        sigma_t: 0.25,
        albedo: 0.9,
        g: 0.6,
    };
    b.medium_box(Vec3::ZERO, Vec3::new(4.0, 2.5, 5.0), haze);
    b.build("fog", camera, 1.0)
}

/// The two rooms of [`door`] and its camera.
fn door_rooms() -> (SceneBuilder, Camera) {
    let mut b = SceneBuilder::default();
    let wall = b.material(room_wall());
    let floor = b.material(glossy_floor());
    let light_room_floor = b.material(Material::diffuse(Vec3::splat(0.55)));
    let door = b.material(Material::diffuse(Vec3::new(0.45, 0.32, 0.22)));
    let [metal, red, blue] = furniture_materials(&mut b);
    let light = b.material(Material::diffuse(Vec3::ZERO).emitting(Vec3::new(600.0, 540.0, 450.0)));

    let (w, h, d) = (7.0, 2.5, 5.0);
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    // Floors, ceiling, outer walls.
    b.quad(Vec3::ZERO, x * 4.0, z * d, floor)
        .quad(x * 4.0, x * 3.0, z * d, light_room_floor)
        .quad(y * h, x * w, z * d, wall)
        .quad(Vec3::ZERO, y * h, z * d, wall)
        .quad(x * w, y * h, z * d, wall)
        .quad(Vec3::ZERO, x * w, y * h, wall)
        .quad(z * d, x * w, y * h, wall);
    // The dividing wall at x = 4, with the doorway z ∈ [2, 3], y ∈ [0, 2.1].
    let door_height = 2.1;
    b.quad(x * 4.0, y * h, z * 2.0, wall)
        .quad(x * 4.0 + z * 3.0, y * h, z * 2.0, wall)
        .quad(
            x * 4.0 + z * 2.0 + y * door_height,
            y * (h - door_height),
            z,
            wall,
        );
    // The door, hinged at z = 2, swung 12° into the light room.
    let angle = 12f32.to_radians();
    let leaf = Vec3::new(angle.sin(), 0.0, angle.cos()) * 0.98;
    b.quad(x * 4.0 + z * 2.0, leaf, y * door_height, door);
    // The light: a 1 m² panel under the light room's ceiling, facing down.
    b.quad(Vec3::new(5.6, h - 0.01, 3.4), x, z, light);
    // Furniture in the camera room.
    b.sphere(Vec3::new(2.2, 0.55, 2.4), 0.55, metal)
        .cuboid(
            Vec3::new(0.5, 0.0, 3.3),
            Vec3::new(1.4, 0.9, 4.4),
            false,
            red,
        )
        .sphere(Vec3::new(3.2, 0.3, 1.2), 0.3, blue);
    let camera = Camera {
        eye: Vec3::new(0.35, 1.5, 0.35),
        target: Vec3::new(3.6, 0.7, 2.9),
        fov_degrees: 62.0,
    };
    (b, camera)
}

/// "Uplight": a room lit only by a floor lamp whose shade opens upward, as interiors often are.
/// The lamp throws a pool of light on the ceiling, and everything else sees the light only
/// after it bounces off that pool. Light sampling finds the lamp only from the ceiling; from
/// the rest of the room the pool is a bright patch that only scattering can find.
///
/// Room `x, z ∈ [0, 5]`, `y ∈ [0, 2.6]`, metres; the lamp stands at `x = z = 3.9`, its 0.2 m
/// square emitter 1.7 m up, facing up inside a 0.3 m square shade that rises to 2.0 m.
pub fn uplight() -> Scene {
    let mut b = SceneBuilder::default();
    let wall = b.material(room_wall());
    let ceiling = b.material(Material::diffuse(Vec3::splat(0.8)));
    let floor = b.material(glossy_floor());
    let shade = b.material(Material::diffuse(Vec3::new(0.55, 0.50, 0.40)));
    let [metal, red, blue] = furniture_materials(&mut b);
    let light = b.material(Material::diffuse(Vec3::ZERO).emitting(Vec3::new(400.0, 360.0, 300.0)));

    let (w, h, d) = (5.0, 2.6, 5.0);
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    b.quad(Vec3::ZERO, x * w, z * d, floor)
        .quad(y * h, z * d, x * w, ceiling);
    b.quad(Vec3::ZERO, y * h, z * d, wall)
        .quad(x * w, z * d, y * h, wall)
        .quad(Vec3::ZERO, x * w, y * h, wall)
        .quad(z * d, y * h, x * w, wall);
    // The lamp: a pole, the shade's four sides and bottom (open at the top), and the emitter
    // facing up inside it.
    let c = Vec3::new(3.9, 0.0, 3.9);
    b.cuboid(
        c - Vec3::new(0.02, 0.0, 0.02),
        c + Vec3::new(0.02, 1.6, 0.02),
        false,
        shade,
    );
    let (lo, hi, r) = (1.6, 2.0, 0.15);
    let corner = |dx: f32, dz: f32| c + Vec3::new(dx * r, lo, dz * r);
    let (sx, sz, sy) = (x * 2.0 * r, z * 2.0 * r, y * (hi - lo));
    for (p, u, v) in [
        (corner(-1.0, -1.0), sx, sy),
        (corner(-1.0, 1.0), sy, sx),
        (corner(-1.0, -1.0), sy, sz),
        (corner(1.0, -1.0), sz, sy),
        (corner(-1.0, -1.0), sz, sx),
    ] {
        b.quad(p, u, v, shade);
    }
    b.quad(c + Vec3::new(-0.1, 1.7, -0.1), z * 0.2, x * 0.2, light);
    // Furniture.
    b.sphere(Vec3::new(2.3, 0.55, 2.6), 0.55, metal)
        .cuboid(
            Vec3::new(0.6, 0.0, 3.2),
            Vec3::new(1.5, 0.9, 4.3),
            false,
            red,
        )
        .sphere(Vec3::new(3.3, 0.3, 1.5), 0.3, blue);
    let camera = Camera {
        eye: Vec3::new(0.35, 1.5, 0.35),
        target: Vec3::new(3.6, 1.1, 3.4),
        fov_degrees: 65.0,
    };
    b.build("uplight", camera, 1.0)
}

/// Registers the materials of a Cornell box's coloured walls, red (left) and green (right), in
/// this order.
fn cornell_walls(b: &mut SceneBuilder) -> [u16; 2] {
    [
        Material::diffuse(Vec3::new(0.63, 0.07, 0.05)),
        Material::diffuse(Vec3::new(0.12, 0.45, 0.09)),
    ]
    .map(|m| b.material(m))
}

/// The unit box `[0, 1]³` open at the front (`z = 0`): white floor, ceiling and back wall, and
/// the walls `left` (`x = 0`) and `right` (`x = 1`), their normals into the box.
fn open_box(b: &mut SceneBuilder, white: u16, [left, right]: [u16; 2]) {
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    b.quad(Vec3::ZERO, x, z, white)
        .quad(y, z, x, white)
        .quad(z, y, x, white)
        .quad(Vec3::ZERO, z, y, left)
        .quad(x, y, z, right);
}

/// "Glossy box": a Cornell-style box with a glossy floor and two glossy spheres of different
/// roughness, lit by a small (0.15 m square) ceiling light. Open at the front.
pub fn glossy_box() -> Scene {
    let mut b = SceneBuilder::default();
    let white = b.material(Material::diffuse(Vec3::splat(0.73)));
    let [red, green] = cornell_walls(&mut b);
    let floor = b.material(Material::glossy(Vec3::splat(0.35), Vec3::splat(0.4), 0.1));
    let gold = b.material(Material::glossy(
        Vec3::splat(0.02),
        Vec3::new(0.95, 0.75, 0.35),
        0.06,
    ));
    let plastic = b.material(Material::glossy(
        Vec3::new(0.1, 0.2, 0.5),
        Vec3::splat(0.25),
        0.35,
    ));
    let light = b.material(Material::diffuse(Vec3::ZERO).emitting(Vec3::splat(60.0)));
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    b.quad(Vec3::ZERO, x, z, floor)
        .quad(y, x, z, white)
        .quad(z, x, y, white)
        .quad(Vec3::ZERO, y, z, red)
        .quad(x, y, z, green)
        .quad(Vec3::new(0.425, 0.999, 0.425), x * 0.15, z * 0.15, light)
        .sphere(Vec3::new(0.3, 0.2, 0.6), 0.2, gold)
        .sphere(Vec3::new(0.72, 0.16, 0.35), 0.16, plastic);
    let camera = Camera {
        eye: Vec3::new(0.5, 0.5, -1.25),
        target: Vec3::new(0.5, 0.45, 0.5),
        fov_degrees: 40.0,
    };
    b.build("glossy-box", camera, 1.0)
}

/// "Covered": a Cornell box whose only light sits on top of a panel hung under
/// the ceiling, facing up. Only the ceiling and the top of the walls see the light; the rest of
/// the room is lit by the pool it throws on the ceiling, which next-event estimation cannot
/// reach (the emitter is hidden from every point below the panel) and BSDF sampling finds only
/// by chance. Open at the front.
///
/// Room `x, y, z ∈ [0, 1]`, metres; the panel is 0.3 m square, 15 cm under the ceiling; the
/// emitter is 0.24 m square, 2 mm above the panel.
pub fn covered() -> Scene {
    let mut b = SceneBuilder::default();
    let white = b.material(Material::diffuse(Vec3::splat(0.75)));
    let [red, green] = cornell_walls(&mut b);
    let panel = b.material(Material::diffuse(Vec3::splat(0.5)));
    let light = b.material(Material::diffuse(Vec3::ZERO).emitting(Vec3::splat(200.0)));
    let (x, z) = (Vec3::X, Vec3::Z);
    open_box(&mut b, white, [red, green]);
    // The panel, and the emitter on it facing the ceiling.
    b.cuboid(
        Vec3::new(0.35, 0.83, 0.35),
        Vec3::new(0.65, 0.85, 0.65),
        false,
        panel,
    )
    .quad(Vec3::new(0.38, 0.852, 0.38), z * 0.24, x * 0.24, light);
    // Two boxes, as in the Cornell box.
    b.cuboid(
        Vec3::new(0.15, 0.0, 0.5),
        Vec3::new(0.45, 0.6, 0.8),
        false,
        white,
    )
    .cuboid(
        Vec3::new(0.55, 0.0, 0.2),
        Vec3::new(0.85, 0.3, 0.5),
        false,
        white,
    );
    let camera = Camera {
        eye: Vec3::new(0.5, 0.5, -1.25),
        target: Vec3::new(0.5, 0.5, 0.5),
        fov_degrees: 40.0,
    };
    b.build("covered", camera, 2.0)
}

/// "Caustic": a Cornell box lit by a ceiling lamp under a clear glass cover, with a glass
/// sphere on the floor. Every path from the lamp to a diffuse surface passes through glass
/// (light → glass → diffuse → camera, a caustic path): next-event estimation cannot connect
/// through it, so the whole room — the direct light on the walls and the floor, and the
/// focused caustic the sphere throws beside itself — is found only by scattered directions
/// that happen to cross the cover and reach the small lamp behind it. A guide learns those
/// directions; unguided path tracing finds them by chance. Open at the front.
///
/// Room `x, y, z ∈ [0, 1]`, metres; the lamp is 10 cm square, facing down 1 cm under the
/// ceiling, at `x = 0.3, z = 0.6`, inside a glass box (index 1.5) 16 cm square and 4.5 cm deep;
/// the sphere's radius is 0.16 m, index of refraction 1.5.
pub fn caustic() -> Scene {
    let mut b = SceneBuilder::default();
    let white = b.material(Material::diffuse(Vec3::splat(0.75)));
    let [red, green] = cornell_walls(&mut b);
    let glass = b.material(Material::glass(1.5));
    let light = b.material(Material::diffuse(Vec3::ZERO).emitting(Vec3::splat(150.0)));
    let (x, z) = (Vec3::X, Vec3::Z);
    open_box(&mut b, white, [red, green]);
    // The lamp, facing down, and its cover around it.
    b.quad(Vec3::new(0.25, 0.99, 0.55), x * 0.1, z * 0.1, light)
        .cuboid(
            Vec3::new(0.22, 0.95, 0.52),
            Vec3::new(0.38, 0.995, 0.68),
            false,
            glass,
        );
    b.sphere(Vec3::new(0.6, 0.16, 0.42), 0.16, glass);
    let camera = Camera {
        eye: Vec3::new(0.5, 0.5, -1.25),
        target: Vec3::new(0.5, 0.45, 0.5),
        fov_degrees: 40.0,
    };
    b.build("caustic", camera, 1.0)
}

/// The white furnace of [`furnace`] with a glass sphere (index of refraction 1.5, radius 0.35)
/// at its centre, in the camera's view. A lossless dielectric in an isotropic radiance field
/// leaves the field as it is, so the expectation is still `emission / (1 − albedo)`: a render
/// that converges to it checks that the dielectric conserves energy and that paths through it
/// are weighed right.
pub fn glass_furnace(albedo: f32, emission: f32) -> Scene {
    let (mut b, camera) = furnace_room(albedo, emission, 1.0);
    let glass = b.material(Material::glass(1.5));
    b.sphere(Vec3::new(0.25, 0.1, 0.6), 0.35, glass);
    b.build("glass-furnace", camera, 1.0)
}

/// The white furnace: the inside of a closed cube whose every face emits `emission` and
/// reflects diffusely with `albedo`. The radiance is the same everywhere and in every direction,
/// `L = emission / (1 − albedo)`, whatever the estimator, so a render must converge to it.
pub fn furnace(albedo: f32, emission: f32) -> Scene {
    furnace_sized(albedo, emission, 1.0)
}

/// The white furnace of [`furnace`], a cube of half-size `half` (metres). Its radiance does not
/// depend on the size; a small one puts every light sample within a metre of its shading point.
pub fn furnace_sized(albedo: f32, emission: f32, half: f32) -> Scene {
    let (b, camera) = furnace_room(albedo, emission, half);
    b.build("furnace", camera, 1.0)
}

/// The furnace cube of half-size `half` and its camera, for [`furnace_sized`] and
/// [`glass_furnace`] to furnish.
fn furnace_room(albedo: f32, emission: f32, half: f32) -> (SceneBuilder, Camera) {
    let mut b = SceneBuilder::default();
    let m = b.material(Material::diffuse(Vec3::splat(albedo)).emitting(Vec3::splat(emission)));
    b.cuboid(Vec3::splat(-half), Vec3::splat(half), true, m);
    let camera = Camera {
        eye: Vec3::new(0.1, 0.2, -0.3) * half,
        target: Vec3::new(0.4, 0.1, 1.0) * half,
        fov_degrees: 70.0,
    };
    (b, camera)
}

/// The furnace of [`furnace`] (faces emitting `emission`, reflecting with `albedo`) filled with
/// a medium that scatters without absorbing (albedo 1, extinction 0.8 per metre, g = 0.5). A
/// medium that neither absorbs nor emits leaves an isotropic radiance field as it is, so the
/// expectation is still `emission / (1 − albedo)`: a render that converges to it checks free
/// flights, transmittance in next-event estimation, the phase function's sampling and the
/// volume guide's mixture. Paths may scatter many times in the medium, so they are cut after
/// 200 events, not 10 (the part lost is far below the statistical error).
pub fn medium_furnace(albedo: f32, emission: f32) -> Scene {
    let (mut b, camera) = furnace_room(albedo, emission, 1.0);
    b.global_medium(Medium {
        sigma_t: 0.8,
        albedo: 1.0,
        g: 0.5,
    });
    let mut scene = b.build("medium-furnace", camera, 1.0);
    scene.max_depth = 200;
    scene
}
