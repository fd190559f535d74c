"""People whose foot is hidden (behind another agent, or below the image) get their contact from
their top and fitted height (staticdepth/geometry/agent_contact.py: contact_from_top,
contacts_from_top).

The scene is rendered here, apart from the plane fit's model: bodies are point clouds of an
ellipsoid trunk on two legs (not the disk model the estimate assumes), projected into an instance
map, nearer bodies painted over farther ones; the truth is the ground point under each body's
lowest silhouette point."""
import numpy as np

from staticdepth.dataset.schema import empty_agents
from staticdepth.geometry.agent_contact import PersonHeights, contact_from_top
from staticdepth.geometry.alignment import agents_at_contact
from staticdepth.geometry.projection import ray_grid

W, H = 320, 240
K = np.array([[260.0, 0, 160.0], [0, 260.0, 120.0], [0, 0, 1.0]])
CAM_H = 4.0                       # metres; the tests work in units of it (plane n . P = 1)
PITCH = np.radians(30.0)
# camera frame (x right, y down, z forward); the ground normal points down to the ground
N = np.array([0.0, np.cos(PITCH), np.sin(PITCH)])
FWD = np.array([0.0, -np.sin(PITCH), np.cos(PITCH)])     # horizontal, away from the camera
RIGHT = np.array([1.0, 0.0, 0.0])


def body_points(x: float, y: float, height_m: float, rng) -> np.ndarray:
    """Camera-frame points (units of the camera height) of a person standing at ground position
    (x right, y forward, metres): two legs (0.07 m cylinders, 45% of the height), an ellipsoid
    trunk and a 0.1 m head sphere."""
    base = N * 1.0 + (x * RIGHT + y * FWD) / CAM_H        # the ground point under the body
    pts = []
    leg = 0.45 * height_m
    for side in (-0.1, 0.1):
        a = rng.uniform(0, 2 * np.pi, 4000)
        z = rng.uniform(0, leg, 4000)
        pts.append(np.stack([side + 0.07 * np.cos(a), 0.07 * np.sin(a), z], 1))
    a = rng.uniform(0, 2 * np.pi, 20000)
    b = np.arccos(rng.uniform(-1, 1, 20000))
    c = leg + 0.5 * (0.42 * height_m) * (1 + np.cos(b))        # trunk from leg top up
    pts.append(np.stack([0.2 * np.sin(b) * np.cos(a), 0.13 * np.sin(b) * np.sin(a), c], 1))
    a = rng.uniform(0, 2 * np.pi, 8000)
    b = np.arccos(rng.uniform(-1, 1, 8000))
    c = height_m - 0.1 + 0.1 * np.cos(b)
    pts.append(np.stack([0.1 * np.sin(b) * np.cos(a), 0.1 * np.sin(b) * np.sin(a), c], 1))
    p = np.concatenate(pts)
    return base + (p[:, :1] * RIGHT + p[:, 1:2] * FWD - p[:, 2:3] * N) / CAM_H


def box_points(x: float, y: float, rng, size=(2.0, 1.0, 1.1)) -> np.ndarray:
    """A parked car: the surface of a box (width, length, height in metres) on the ground."""
    w, ln, h = size
    p = rng.uniform(-0.5, 0.5, (60000, 3)) * np.array([w, ln, h])
    face = rng.integers(0, 3, len(p))
    k = np.arange(len(p))
    p[k, face] = np.sign(p[k, face]) * np.array([w, ln, h])[face] / 2
    p[:, 2] += h / 2
    base = N * 1.0 + (x * RIGHT + y * FWD) / CAM_H
    return base + (p[:, :1] * RIGHT + p[:, 1:2] * FWD - p[:, 2:3] * N) / CAM_H


def render(people: list[tuple[float, float, float]], seed: int = 0, car=None):
    """Instance map (people 1.., a car ``car = (x, y)`` last), each person's true contact depth
    (units of the camera height: the ground point under its lowest silhouette point, found with
    no occluder)."""
    rng = np.random.default_rng(seed)
    inst = np.zeros((H, W), np.uint16)
    zbuf = np.full((H, W), np.inf)
    truth = {}
    bodies = [body_points(x, y, hm, rng) for x, y, hm in people]
    if car is not None:
        bodies.append(box_points(car[0], car[1], rng))
    for k, P in enumerate(bodies, start=1):
        uv = P @ K.T
        u, v = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
        low = np.argmax(v)                          # the silhouette's lowest point
        ray = np.linalg.inv(K) @ np.array([u[low], v[low], 1.0])
        truth[k] = 1.0 / (ray @ N)                  # its ray meets the ground here (depth z)
        ui, vi = np.floor(u).astype(int), np.floor(v).astype(int)
        ok = (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
        for a, b, z in zip(ui[ok], vi[ok], P[ok, 2]):
            if z < zbuf[b, a]:
                zbuf[b, a], inst[b, a] = z, k
    return inst, truth


def rows_for(ids):
    rows = empty_agents(len(ids))
    rows["instance_id"] = ids
    rows["class_id"] = 0
    rows["track_id"] = ids
    return rows


def test_contact_from_top_inverts_the_disk_model_in_closed_form():
    # a thin axis: the top point at height s above the contact, straight above it
    for x, y, s in ((0.5, 6.0, 0.45), (-2.0, 11.0, 0.4), (1.0, 3.0, 0.3)):
        foot = N + (x * RIGHT + y * FWD) / CAM_H
        top = foot - s * N
        u, v, w = K @ top
        z = contact_from_top(K, N, 1.0, u / w, v / w, s)
        assert abs(float(z) - foot[2]) < 1e-9
    # a camera twice as high (d = 2): the same pixel and s give twice the depth
    assert abs(float(contact_from_top(K, N, 2.0, u / w, v / w, s)) - 2 * foot[2]) < 1e-9
    # a ray that never reaches the height in front of the camera: NaN
    assert np.isnan(contact_from_top(K, N, 1.0, 160.0, -400.0, 0.4))


def test_hidden_and_cut_people_take_their_contact_from_the_top():
    # 1 walks behind a parked car (4) that hides its feet; 2 stands so near that its feet are
    # below the image; 3 is seen whole
    people = [(-0.3, 8.0, 1.75), (1.0, 2.0, 1.80), (-3.0, 9.0, 1.65)]
    inst, truth = render(people, car=(-0.3, 6.5))
    assert (inst[H - 1] == 2).any()                        # 2 is cut by the image's bottom
    low1 = np.nonzero(inst == 1)[0].max()
    assert (inst[low1 + 1][inst[low1] == 1] == 4).all()    # 1 ends on the car
    rows = rows_for([1, 2, 3, 4])
    rows["class_id"][3] = 2                                # COCO car
    s = {k + 1: p[2] / CAM_H for k, p in enumerate(people)}
    heights = PersonHeights(s, float(np.median(list(s.values()))), (0.03, 0.03))
    Z = np.ones((H, W), np.float32)
    before, _ = agents_at_contact(Z, K, N, 1.0, inst, rows)
    after, _ = agents_at_contact(Z, K, N, 1.0, inst, rows, heights=heights)

    def err(A, k):
        return abs(float(np.median(A[inst == k])) / truth[k] - 1)

    # the hidden foot and the cut one: too far from the lowest pixel, right from the top
    assert err(before, 1) > 0.15 and err(after, 1) < 0.03
    assert err(before, 2) > 0.15 and err(after, 2) < 0.05
    # a person whose foot is seen, and the car, keep the plane's depth at their lowest pixel
    assert err(before, 3) < 0.03
    for k in (3, 4):
        np.testing.assert_array_equal(after[inst == k], before[inst == k])
    # the fitted heights matter: 15% too tall puts 1 nearer by about the same share
    tall = PersonHeights({k: 1.15 * v for k, v in s.items()}, 0.5, (0.03, 0.03))
    off, _ = agents_at_contact(Z, K, N, 1.0, inst, rows, heights=tall)
    assert float(np.median(off[inst == 1])) < 0.95 * float(np.median(after[inst == 1]))


def test_a_person_of_no_fitted_track_takes_the_median_height():
    inst, truth = render([(-0.3, 8.0, 1.70)], seed=1, car=(-0.3, 6.5))
    rows = rows_for([1, 2])
    rows["class_id"][1] = 2
    rows["track_id"] = -1                              # a detector without track ids
    heights = PersonHeights({}, 1.70 / CAM_H, (0.03, 0.03))
    after, _ = agents_at_contact(np.ones((H, W), np.float32), K, N, 1.0, inst, rows,
                                 heights=heights)
    assert abs(float(np.median(after[inst == 1])) / truth[1] - 1) < 0.03


def test_the_plane_depth_at_the_contact_is_the_bound():
    # a foot below the lowest pixel is nearer than it: a height too small for the top (the top
    # ray reaching s far behind) never puts the person farther than its lowest pixel's plane depth
    inst, truth = render([(-0.3, 8.0, 1.75)], seed=2, car=(-0.3, 6.5))
    rows = rows_for([1, 2])
    rows["class_id"][1] = 2
    q = ray_grid(K, W, H) @ N
    v = np.nonzero(inst == 1)[0].max()
    bound = 1.0 / float(np.median(q[v][inst[v] == 1]))
    tiny = PersonHeights({1: 0.05}, 0.4, (0.0, 0.0))
    after, _ = agents_at_contact(np.ones((H, W), np.float32), K, N, 1.0, inst, rows,
                                 heights=tiny)
    assert abs(float(np.median(after[inst == 1])) / bound - 1) < 1e-4
