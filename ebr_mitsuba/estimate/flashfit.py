"""The flash-profile fit: a material's roughness and albedo level read off the flash shot by physics.

With the flash beside the lens (``docs/conventions.md``, "Geometry"), every pixel of the sample is
seen and lit along the same direction, so the half vector is the view direction and its angle θ to
the (mean, flat) normal grows from 0 at the mirror point to 30° in the corners of the near frame.
Divided by the flat-normal diffuse shading ``G(x) = I cos θ / (π d²)`` (unit albedo), the
flash-only image ``F = flash − no-flash`` (radiance units) reads

    g(x) = F(x) / G(x) = ρ(x) + π f_s(θ(x); F₀, r)

(albedo plus the specular lobe, ``f_s`` the GGX term of :mod:`ebr_mitsuba.nets.torch_brdf`, the
one BRDF). The albedo texture ρ(x) does not depend on θ, the lobe depends on nothing else, so the
profile of g over θ separates them: pixels are binned by cos θ into ``bins`` rings of equal pixel
count; each ring's statistic (``ring_statistic``, default ``trimmed``: the mean of the middle 80 %
of its unsaturated g values) is robust to the texture, and the model's ring value is the lobe
averaged over *the same pixels*, so a lobe sharper than the central ring cannot hide in it (with
ring medians, a dark-grouted tile texture seen in EXR picked roughness 0.07 against a truth of
0.25 / 0.85 and the re-render of its flash shot was off by 456 %). For each roughness r of a grid
the level ``L(r) = median_rings((g_ring − π f̄_s(ring; F₀, r)) / p_ring)`` is solved in
closed form (``p_ring``: the ring's albedo share, "The no-flash rings" below). The cost of r is
the mean squared ring residual relative to L, plus two terms that the saturated pixels give (the
tip of a sharp highlight is clipped, so its rings carry no median):

* rings more than half saturated must be at least as bright as their clip level (a lobe too weak
  to saturate them is penalised by how much it falls short, relative to L);
* ``saturation_weight`` × |pixels the model would saturate ⊕ pixels that are saturated| ÷
  max(saturated pixels, 10): a lobe so sharp that it hides inside the central ring would saturate
  pixels that are not saturated; a broad one would miss the clipped tip.

The roughness of lowest cost is kept. F₀ is fixed (``f0``, default 0.04: real dielectrics, the
measured table of ``$EBR_DATA_DIR/measured``). A second hypothesis, a metal (no diffuse,
``g = m · π f_s(θ; 1, r)``, m solved like L), wins when its cost is below ``METAL_MARGIN`` (½) of
the dielectric's; its F₀ per channel is the least-squares scale of the flash-only image on the
unit lobe ("Noise" below).

Metal or dielectric. The metal hypothesis also needs a lobe that a diffuse surface cannot mimic:
its roughness must be below ``METAL_MAX_ROUGHNESS`` (0.75). Over the near frame's view angles (0 to
30°) the unit GGX lobe falls to 0.18 / 0.40 / 0.68 / 0.94 of its centre value at roughness 0.6 /
0.7 / 0.8 / 0.9 and rises to 1.15 at 1, so above about 0.75 a metal with no diffuse part has the
profile of a diffuse one, and a fall-off the model misjudges (a phone's field of view is a guess,
a lens vignettes) then tips the choice, its free level m fitting what the dielectric's fixed F₀
cannot. The real metal sets here have mean roughness 0.07–0.59 and the procedural metals draw
0.08–0.55. The decision is recorded as ``FlashFit.decision`` and estimate.json's
``flash_fit.decision``: ``{"metal_ratio"`` (the best metal's cost over the best dielectric's; below
``METAL_MARGIN`` the metal fits better), ``"metal_level"`` (its m before the clamp to 1),
``"metal_roughness"}``. Rough dielectrics show metal ratios near 1 (the flat metal lobe fits them as
well as the diffuse term), true metals 2e-4–0.3. Measured (2026-12-07): of the 72 validation
captures (``configs/data_real_val.toml``, ``configs/data_real_val2.toml``) one changes, a glossy
facade set (roughness 0.057, F₀ 0.084, diffuse 0.004) read as a metal of roughness 0.78 (metal
ratio 3e-5): its mean per-map RMSE went 0.2095 → 0.0455, the second set's mean 0.0433 → 0.0399
(roughness 0.0873 → 0.0742), the first set's unchanged (0.0436); on the real flash-only photos of
``ebr gallery`` a tan plaster and a white scratched panel, metals of roughness 1 with F₀ clipped at
1 and no diffuse map before, are dielectrics with their texture now.
Known failure: a high-contrast two-tone texture without a visible highlight (e.g. a 0.55 / 0.1
checker of roughness 0.3–0.6 seen in EXR, no clipping) makes the ring statistics jump between the
tones (less with ``trimmed`` than with ``median``), which can let the metal hypothesis win
(diffuse 0); ``--no-flash-fit`` avoids it. A dark stone with light patches (a flash-only photo of
``ebr gallery``) still reads as a metal of roughness 0.59.

The diffuse map is the level times a texture pattern: the flash photo with the fitted lobe
removed, divided by its own local mean over a box of ``pattern`` × the image side (grey, so the
level keeps the colour): ``ρ(x) = L_c · P(x)``, ``L_c`` per channel the mean of
``(F_c − S)/G`` over the unsaturated pixels where the fitted lobe S is below half the level
(``level_statistic`` ``clean``; a median would pick one tone of a two-tone texture). The
earlier statistic, the mean of the middle 80 % (``trimmed``), is biased for a skewed texture:
a brick wall's bright mortar is the top decile it cuts, so the level came out 7–21 % low per
channel (redder than the wall). On the validation captures (``configs/data_real_val.toml``, 24)
the diffuse RMSE went from 0.0565 (trimmed) to 0.0530 (clean), on the 24 near-far validation
captures from 0.0620 to 0.0610; the plain mean over all unsaturated pixels gave 0.0533 (it
keeps the residue of a glossy tile's highlight). The pattern's low frequencies are then put back
(``pattern_lows``, "Low frequencies" below): ``ρ(x) = L_c · B_c(x) · P(x)``. ``ebr estimate``
blends this map with the network's diffuse map scaled per channel to the fitted level
(``network_weight``, the network's share; :meth:`FlashFit.with_network_diffuse`): the network's
map is denoised and free of the photo's shading, the photo's pattern is exact in its texture;
chosen on the validation set ``configs/data_real_val.toml`` (training materials and maps, not
the test split): mean diffuse RMSE 0.0619 (photo pattern) / 0.0627 (scaled network map) / 0.0567
(the blend), with the trimmed level; with the clean level, weights 0.35 / 0.5 / 0.65 gave 0.0534 /
0.0530 / 0.0538 (the default was 0.5 until 2026-12-06; with the low frequencies put back, see
below, 0.6).
Above 256² the photo's per-pixel noise grows as its pixels shrink while the network's map
sharpens: the pattern's detail is shrunk by its signal share (``pattern_detail``, "Detail"
below) and the photo pattern's share falls as √(256 / size) (:meth:`FlashFitConfig.weight_for`:
0.28 at 512², 0.2 at 1024²; without ``pattern_detail`` as 256 / size, 0.2 and 0.1; re-checked
with the low frequencies on the five 1024² validation captures of "Fit size" below, a share
falling as (256 / size)^p for p = 0 / 0.25 / 0.5 gave a mean diffuse RMSE of 0.0304 / 0.0292 /
0.0287: tiles prefer the fall, marble and wood none). The
flash photo is used for the pattern because it is the brighter, less quantised of the two shots;
its low frequencies (flash fall-off, environment gradients) are what the local mean divides out,
together with the albedo's own low frequencies. Shading by the normals' relief stays in the
pattern (it is read as albedo texture).

Low frequencies. What the local mean divides out of the flash photo is the environment's light
and the flash's fall-off, but also the albedo's variation at the scale of the box and above
(a plank darker than its neighbour, a stain). The flash-only image F knows that variation
without the environment: the per-pixel ratio ``(F_c − S)/G`` (the level's ratio) is the albedo
itself, noisy pixel by pixel (F is the difference of two shots) but not over a box. ``B_c`` is
that ratio averaged over the pattern's box around each pixel, counting only the level's clean
pixels (unsaturated, the lobe below half the level), relative to its mean (1 where a box holds
under ``LOWS_MIN_SHARE`` clean pixels). On the validation captures (``configs/data_real_val.toml``,
24, and ``configs/data_real_val2.toml``, 48; training materials and maps) the estimate's diffuse
RMSE went 0.04758 → 0.04624 and 0.03088 → 0.02976 (network weight 0.5; a grey ``B``, the
channels' mean: 0.04646 / 0.02996; boxes of half and twice the radius: 0.04762 / 0.04731 on the
first set); with it the network weights 0.4 / 0.5 / 0.6 / 0.7 gave 0.04701 / 0.04624 / 0.04605 /
0.04642 and – / 0.02976 / 0.02926 / 0.02910, hence 0.6. Giving the network's map the same low
frequencies instead of its own made it worse (0.04736). Tried and not adopted (2026-12-06):
with the low frequencies back the box (``pattern``) only splits the detail between the flash
photo (finer than the box) and the flash-only ratio (coarser); boxes of 1/4, 1/8, 1/16, 1/32,
1/64 and 1/128 of the side gave 0.04631 / 0.04606 / 0.04584 / 0.04551 / 0.04505 / 0.04518 on the
first validation set and – / 0.02926 / 0.02864 / 0.02792 / 0.02767 / 0.02807 on the second
(network weight 0.6; 0.5 with the 1/64 box: 0.04511 / 0.02792), but on the test split
(``docs/models.md``, one ``ebr bench models`` run) 1/64 made the estimate's diffuse RMSE worse,
0.0262 → 0.0268 (near-far 0.0319 → 0.0323), so the box stays at 1/8.

The no-flash rings. The ring statistics still carry the albedo texture's mean over each ring: a
texture brighter at the frame's centre (or a rock whose lit faces happen to sit there) reads as
a lobe, too broad a one. The no-flash shot sees the same albedo under light that does not vary
across the flat sample (a distant environment), so each ring's no-flash mean over the same kept
pixels, relative to all rings' mean, is the ring's albedo share ``p_ring`` (``noflash_albedo``,
default on; clamped to [P_RING_MIN, 1 / P_RING_MIN]; left at 1 when the no-flash shot is darker
than NOFLASH_MIN or the far pair is given). The model's ring value is then ``L · p_ring + π
f̄_s``. Lens vignetting, being in both shots, is in ``p_ring`` too. On the validation captures
(``configs/data_real_val.toml``, 24, near shots) the roughness RMSE against the truth maps went
from 0.119 to 0.103 (Rock006 1.00 → 0.76, truth 0.64), on the near shots of the 24 near-far
validation captures from 0.108 to 0.090. What it cannot see: the environment's own reflection
in a glossy sample's no-flash shot is taken for albedo.

Relief. A normal map's relief broadens the highlight as roughness does: the pixels of a glazed
tile's bevels and pits, tilted, catch the flash away from the mirror point, so one lobe fitted to
the rings reads the tile rough (acg_Tiles011, roughness 0.19 with normals spread by 0.13, read
0.47 and 0.55 under two maps). The flat faces still give a sharp lobe at the mirror point and the
tilted pixels a broad skirt, which two lobes fit far better than one. So every pair of grid
roughnesses is tried as ``w · lobe(r_sharp) + (1 − w) · lobe(r_broad)`` (w in RELIEF_WEIGHTS, F0
shared), each judged on the rings as a single lobe is (level, residual, clipped-ring floor); when
the best pair's cost is RELIEF_GAIN (2) times below the best single lobe's and RELIEF_MARGIN
(1e-4, a 1 % rms ring residual) below it, the relief is taken for the broad lobe and the sharp
lobe's roughness is the material's (``relief``, default on; the near rings, read with the
no-flash shares, also when the far pair is given; ``FlashFit.relief`` and estimate.json's
``flash_fit.relief`` record the pair). The assumption is that the broad lobe is relief, not a
second, rougher material in the same sample: a sample of two roughnesses side by side would
come out as its smoother part. On the validation captures (``configs/data_real_val.toml``, 24)
it took effect in 3: Tiles011 0.47 → 0.19 and 0.55 → 0.31 (truth 0.19), Metal034 0.14 → 0.12
(truth 0.07); the RMSE of the per-capture roughness against the truth's mean went from 0.112
to 0.067, the roughness map's RMSE of ``ebr estimate`` from 0.0838 to 0.0746 (on the 24
near-far validation captures, far pair used, 0.0655 → 0.0650); in none of the other 21 did the
two lobes win. On synthetic relief (half the pixels
tilted by slopes of 0.2–0.4, roughness 0.3; ``tests/test_flashfit.py``) one lobe reads 0.42–0.48,
the sharp lobe 0.33–0.38; below the central ring's size (roughness 0.15 at 128²) the sharp lobe
is not resolved and can come out at the grid's floor. On the second validation set
(``configs/data_real_val2.toml``, 48 captures) it did not help: roughness RMSE 0.0919 without,
0.0939 with (mean per-map RMSE 0.0453 / 0.0458); it stays on for the glazed tiles it was made
for, a choice to revisit with more relief-heavy captures.

The pixel-median reading. The ring statistics are means (the middle 80 % of each ring's values):
when more than a tenth of a ring's pixels are lifted by the glints of tilted pixels (the grains,
ridges and pits of a rough sample, whose relief is too broad for the two-lobe reading above) or by
the residue of a bright environment, the trimmed mean moves with them and one lobe reads the
sample rougher. A second reading works pixel by pixel: each pixel's residual ``g(x) − L·p(x) −
π f_s(θ(x))``, with its own albedo share p(x) (the no-flash shot over its mean over the pixels
read), has a ring median of zero for the right lobe and level whatever a minority of the ring's
pixels does. For each roughness of the grid the level is searched around the profile's (from
``MEDIAN_LEVELS``, then finer), and the roughness of the smallest mean squared ring median (over
the level) is this reading. The roughness is the mean of the two readings (``pixel_median``,
default on; near shots with the no-flash shares read, and not when the relief reading took
effect, which has taken the tilted pixels apart already, nor with the far pair). A reading below
``MEDIAN_MIN_ROUGHNESS`` is not used: a lobe that narrow lights a few central pixels which ring
medians ignore, so the medians cannot tell it from no lobe (acg_Rock020 read 0.04 for a truth of
0.51). ``FlashFit.pixel_median`` and estimate.json's ``flash_fit.pixel_median`` record
``{"roughness", "profile", "used"}``. On the validation captures (photos; dielectric captures the
fit reads as such) the RMS error of the fitted roughness against the truth map's mean went 0.0564
→ 0.0476 on ``configs/data_real_val.toml`` (22 captures; better by over 0.01 in 4, worse in 1) and
0.160 → 0.154 on ``configs/data_real_val2.toml`` (45; better in 14, worse in 1); the median reading
alone, on the first set 0.0485 and 16 captures worse than the profile across the two. ``ebr
estimate``'s roughness map (after the misfit fallback below, which takes the captures the reading
helped most on the first set): RMSE 0.0663 → 0.0666 and 0.0939 → 0.0873, mean per-map RMSE 0.0435
→ 0.0436 and 0.0449 → 0.0433, held-out re-render unchanged (0.709, 1.050); per capture the
roughness map is better (by over 0.005) in 13 and worse in 1. Adding the central ring's mean
residual to the median cost (weight 1, so that a sharp lobe cannot hide) made both sets worse
(0.0700 / 0.133). On the test split (``docs/models.md``, measured after the choice) the
estimate's roughness RMSE went 0.0653 → 0.0604, its mean per-map RMSE 0.0317 → 0.0305.
The two readings' shares (``median_weight``, the median's; 0.5 above) re-checked on 2026-12-08
with the roughness pattern on, ``ebr estimate``'s roughness map per set (``configs/data_real_val.toml``
24, ``configs/data_real_val2.toml`` 48, ``configs/data_proc_val.toml`` 24 procedural draws) at
weights 0.5 / 0.75 / 1: 0.06422 / 0.06458 / 0.06503, 0.07290 / 0.07012 / 0.06795 and 0.10665 /
0.10859 / 0.11013 (mean per-map 0.04188 / 0.04194 / 0.04219, 0.03833 / 0.03764 / 0.03711, 0.05231
/ 0.05279 / 0.05318; held-out re-render within 0.0001). Over all 96 the median alone is ahead
(0.0792 → 0.0778), but only through the second set: two sets of three prefer the even blend, so
it stays. The median alone helps where relief makes the ring means over-read (acg_Ground080
0.0629 → 0.0584, a plastered wall 0.0513 → 0.0463) and hurts flat samples (a wallpaper 0.0114 →
0.0189, a concrete 0.0328 → 0.0408).
Where the two readings disagree by more than ``median_alone`` (0.1), the median's alone is taken
(2026-12-08): a gap that wide means the glints of tilted pixels lift the ring means (the flat
samples the median hurts read both alike, within about 0.05). Chosen on the same 96 validation
captures, ``ebr estimate``'s roughness map at gaps of 1 (always the blend) / 0.1 / 0.06 / 0: per
set 0.06422 / 0.06422 / 0.06422 / 0.06503, 0.07290 / 0.07104 / 0.06971 / 0.06795 and 0.10665 /
0.10665 / 0.10820 / 0.11013 (all 96: 0.07917 / 0.07824 / 0.07796 / 0.07777; held-out re-render
within 0.0001); 0.1 is the smallest gap that leaves no set worse than the blend. It moves one
capture of the 96 (acg_Snow003, profile 0.84, median 0.61, truth 0.611: roughness RMSE 0.118 →
0.029), so the evidence for it is that one capture and the reason above; at 0.06 a procedural
fabric went 0.147 → 0.185.

The far pair. A near-far capture (``docs/conventions.md``, "Geometry") adds a far flash / no-flash
pair on the same pixel grid (the far frame is the same sample square), its flash as far as its
lens and as bright at the sample. Its view angles stay below 8°, so per pixel ``g_far(x) = ρ(x) +
π f_s(θ_far(x))`` with θ_far small everywhere: over the same pixels of a ring, the near ring's
statistic minus the far ring's mean is ``π f̄_s(ring, near) − π f̄_s(ring, far)`` — the albedo
texture cancels, whatever it is (a texture brighter at the frame's centre, which the near rings
alone read as a lobe, no longer biases the roughness). With :class:`FarPair` given, the pixels
saturated in either pair are left out of both, the metal-or-dielectric choice is made on the near
rings as above, and the roughness of that hypothesis is the one of lowest cost on these
differences (relative to the near level, plus the near saturation terms); the level, F₀ of a
metal and the maps come from the near shots as before. The far flash intensity is the near one ×
(far / near distance)² unless ``capture.json`` states both (``ebr estimate``).

Detail. Above 256² the pattern's detail — the pattern minus itself area-averaged to 256² and
upsampled — is mostly the photo's per-pixel noise (64 spp, or a sensor's). The no-flash shot's
pattern (the same local-mean ratio) sees the same albedo detail under independent noise, so the
covariance of the two details over the unsaturated pixels is the detail's signal power and
``g = cov(d_flash, d_noflash) / var(d_flash)``, clipped to [0, 1], its signal share: the pattern
becomes ``low + g · d_flash`` (a Wiener gain, one for the whole frame; ``pattern_detail``, default
on). Relief shading that differs between the two lights counts as noise. Chosen on a 1024² 64-spp
validation capture (``procedural:wood:5`` under ``procedural:8``, not a benchmark capture): the
photo pattern's diffuse RMSE 0.0599 → 0.0426; blended with the network's map at weights 0.5 /
0.75 / 0.875 / 1, 0.0346 / 0.0277 / 0.0273 / 0.0293 without the shrinkage and 0.0287 / 0.0267 /
0.0274 / 0.0293 with it — hence the slower fall of the photo's share with it (0.75 at 1024²).

Fit size. Photos larger than ``fit_size`` (256²) are profile-fitted on an area-averaged copy;
the maps are made at full size. 256² is the size of the validation captures every threshold here
(``misfit_limit``, ``RELIEF_GAIN``, the ring statistics) was chosen at, so a capture reads the same
constants whatever its pixel count: at 512² the rings of a larger photo resolve a texture's
highlights, a procedural tile set's misfit fell from 0.0048 to 0.0025 (under the limit) and its
roughness from 0.48 to 0.36. On 1024² 64-spp validation captures (procedural ``metal:4``,
``tiles:6``, ``leather:2``, ``wood:5`` under procedural maps 11, 12, 13, 8; none a benchmark
capture) the roughness RMSE fitted at 256² / 512² was 0.0348 / 0.0348, 0.3022 / 0.3216, 0.1387 /
0.1472 and 0.0626 / 0.0626 (the earlier default was 512, chosen for memory).

Misfit. The kept profile's ring residual (mean squared, relative to the level: the fit term of
its cost, the two-lobe pair's for a relief; ``FlashFit.misfit``, estimate.json's
``flash_fit.misfit``) tells whether one lobe over the albedo describes the rings at all. On the
validation captures (``configs/data_real_val.toml``, 24) it is 1e-5–9e-4 for the 20 roughnesses
read within 0.1 of the truth and 0.007–0.022 for the four read 0.11–0.12 off (a rusty painted
metal 0.70 for 0.82, acg_Rock006 twice 0.75–0.76 for 0.64, acg_Tiles011 0.31 for 0.19: relief
and texture the single lobe misreads). Above ``misfit_limit`` (0.003, between the two groups)
``ebr estimate`` keeps the network's roughness map (``FlashFit.with_network_roughness``; the
fit's diffuse and F0 stay): validation roughness RMSE 0.0734 → 0.0663, mean per-map RMSE 0.0459
→ 0.0441, the other maps unchanged; any limit from 0.001 to 0.007 picks the same four. A metal,
and a roughness read off the far pair, record no misfit and keep the fit. On the second
validation set (``configs/data_real_val2.toml``, 48 other captures, chosen after this choice)
the fallback held: roughness RMSE 0.0998 → 0.0939, mean per-map RMSE 0.0472 → 0.0458; on the
test split it did not (``docs/models.md``: 0.0640 → 0.0653). Caveat (2026-12-07): both validation
sets draw the training materials, whose roughness the network has partly memorised (its mean
roughness scores an RMS of 0.075 against the truth there, its map an RMSE of 0.141 on the test
split's unseen materials), so they favour any choice that leans on the network's output. On 24
Mitsuba captures of new procedural draws (seed 7100, the validation set's maps; no memorised
texture) two profiles misfit, and the fallback made both worse (roughness RMSE 0.0280 → 0.0465,
0.0525 → 0.0590); on 72 further draws (seed 7300, 2026-12-07) seven misfit and the fallback was
better in four (their mean roughness RMSE 0.2368 → 0.2314): neutral. The fallback stays until a
validation split of real materials held out of training can decide it.

Tried and dropped (2026-12-07): after the misfit fallback, letting the network's diffuse map take
over from the photo pattern as the fitted lobe's share of the level rises (weight ``w + (1 − w) ·
min(s, 1)``, s = π f_s / mean(L)), to fill the dark hole an untrusted lobe leaves at the mirror
point (a glittering terrazzo of ``ebr gallery``, misfit 0.021). On the validation captures' 8
misfits the diffuse RMSE went 0.04595 → 0.04547 and 0.02927 → 0.02923 (applied to every capture:
neutral), but on the gallery's real photos the network's map under the highlight is a dark
reddish blob of its own, and the input's re-render got worse in 10 of 13 photos (0.387 → 0.426 on
the terrazzo, 0.543 → 0.612 on a cracked plaster).

``ebr estimate`` runs the fit by default after the network (``--no-flash-fit``: the network's
maps) and keeps the network's normals; ``ebr bench models`` scores both on the test split
(``docs/models.md``).

Noise. The rings are read off ``F`` as it is, negative pixels included (near and far shots):
photo noise is symmetric about the signal, and where the signal is nothing but the tail of a
sharp metal lobe, clamping each pixel of flash − no-flash at 0 (as the rings did until
2026-12-04) turned the noise into a positive floor in every ring, a false albedo level that only
the dielectric hypothesis can explain. A polished copper (acg_Metal034, roughness 0.074, F0
0.77 / 0.44 / 0.002) under a dark cellar map read as a dielectric of roughness 0.12 with F0 0.04;
read unclamped it is a metal of roughness 0.09. On the validation captures
(``configs/data_real_val.toml``, 24) it was the only metal decision that changed, and four other
roughnesses moved by one grid step (0.01): mean per-map RMSE 0.0505 → 0.0483 (specular 0.0276 →
0.0198, roughness 0.0746 → 0.0738), held-out re-render 0.838 → 0.780 (without that capture
0.0835 → 0.0834). A metal's F0 per channel is the least-squares scale of the unclamped
flash-only image on the unit lobe over the unsaturated pixels; the median of the per-pixel
ratios it replaces was 0 when most pixels hold only noise (the copper under another map, near-far
validation: F0 at its 0.001 floor, now 0.17 / 0.08 / 0.001). The diffuse level and pattern are
still made from the clamped image: unclamped there, the validation diffuse RMSE went from 0.0512
to 0.0515 (bricks darker), nothing else changed. With this paragraph's and the next one's
changes together: validation mean per-map RMSE 0.0505 → 0.0469 near (24 captures), 0.0506 →
0.0473 near-far (24; diffuse 0.0609 → 0.0528, specular 0.0283 → 0.0235, held-out re-render
0.831 → 0.794: the copper was a dielectric with a diffuse map there).

The lobe per pixel. A pixel's lobe depends on its view angle θ alone and is tabulated
(:class:`_LobeTable`) uniformly in θ from 0: the core of a sharp lobe (roughness 0.074: α =
0.0055 rad) lies within 1 − cos θ < 2e-5, inside the first interval of the table uniform in
cos θ used until 2026-12-04, which was off by 55 % of the peak there. For roughness below
FOOTPRINT_ROUGHNESS (0.3) the lobe is averaged over FOOTPRINT_SAMPLES² (9) points of each
pixel, as the photo integrates it (a box filter); read at pixel centres a roughness-0.08 lobe's
sum over the 128² frame is 2.4 % low, averaged over the footprints within 0.1 %. With both the
copper above reads roughness 0.08 and F0 0.54 / 0.28 / 0.001; on the 24 validation captures
only its maps changed: mean per-map RMSE 0.0483 → 0.0468 (specular 0.0198 → 0.0144), the
held-out re-render of that capture 16.8 → 17.5 (a highlight this sharp that is not exactly
right scores worse the sharper it is; the others unchanged). Its roughness and F0 are still off
by about one grid step and 30 % (cause not found; its normals are flat). The full-size maps of a
photo larger than FOOTPRINT_MAX_SIZE (1024) read the lobe at pixel centres: the footprint's
error falls with the pixel's area (at 1024² about 2.4 % / 64 for roughness 0.08), while its nine
points per pixel cost 9 × 8 bytes per table weight (at 2048², with the view directions they are
made of, the peak of ``ebr estimate`` went from 2.1 to 4.3 GB; docs/bench/estimate.md).

Tried and dropped (2026-12-05): the network's mean roughness as a Gaussian prior on the fitted
one, weighed against each grid roughness's rise in cost above the minimum. On the validation
captures (``configs/data_real_val.toml``, 24) the fitted roughness's RMSE against the truth maps
is 0.0734, the network's mean 0.0824 (the materials' own spread, what a perfect constant scores,
0.0571); over prior spreads 0.03–0.4 and cost tolerances 0.03–3 × the minimum cost the prior gave
0.0721–0.0818, the best only for the loosest prior. The fit's large errors are not flat minima a
prior could settle: a rock (acg_Rock006) read 0.76 against a truth of 0.64 has its cost at the
true roughness 0.064 above the minimum, more than the minimum itself, a confident misreading of
its relief.

Tried and dropped (2026-12-06): a Toksvig correction for relief, ``α² − k · var(slopes)`` (α the
fitted roughness squared, the slopes of the shading normals fitted before the map's shrinkage,
:mod:`.shading_normals`). On the validation captures (``configs/data_real_val.toml``, 24; the 21
dielectrics without a two-lobe relief) the per-capture roughness error against the truth's mean
correlates with the truth's slope variance by 0.23 and with the fitted slopes' by −0.03 (the 19
with fitted normals; the two glossy ones keep the network's and were left uncorrected): the
deepest relief sets read right (a thatch, slope variance 0.19, 0.88 for 0.89; a brick set, 0.16,
0.54 for 0.545) while a rock of the same relief reads 0.11 high and a rusty painted metal 0.12
low. The RMSE of the per-capture roughness against the truth's mean was 0.0577 uncorrected and
0.0579 / 0.0587 / 0.0658 / 0.134 for k = 0.05 / 0.1 / 0.25 / 0.5.

Tried and dropped (2026-12-07): the lobe read at each pixel's own normal instead of the flat one
(the table looked up at the angle between the pixel's view direction and a given normal map, the
rings and the level as before), so that the relief's tilted pixels no longer read as a broader
lobe. On 34 dielectric validation captures with shading normals (``configs/data_real_val.toml``,
24, and the first 21 of ``configs/data_real_val2.toml``) the RMS error of ``ebr estimate``'s
roughness against the truth's mean was 0.0575 at the flat normal, 0.0579 at the *true* normal maps
(bias −0.009 → −0.035: it helps the relief-heavy sets, a roofing tile 0.805 → 0.655 for 0.70,
snow 0.725 → 0.60 for 0.61, and makes others read smooth, a brick set 0.54 → 0.50 for 0.545),
0.0570 at the estimate's normal map and 0.0653 at its unshrunk slopes (better by over 0.01 in 5,
worse in 10). Even perfect normals do not remove the over-read on average.

Tried and dropped (2026-12-07): roughness by tone. Real tile and brick sets tie roughness to
albedo (per-pixel correlation −0.94 to −0.99 for three tile sets, +0.98 for a brick set), and the
true roughness as a least-squares line in log albedo per material would lower the validation
captures' roughness RMSE a lot (acg_Bricks020 0.090 → 0.020). So the profile was read twice more,
on the pixels darker and brighter than the median of a tone image (the no-flash shot, or its
geometric mean with the flash-only ratio), the map made as a step or a line between the two
halves' roughnesses. On the 18 dielectric validation captures (``configs/data_real_val.toml``)
whose fit the estimate keeps, the halves read differences the truth does not have (a fabric 1.00
/ 0.68, a concrete 0.905 / 0.805) and on the glazed tile set they were made for the wrong way
round (grout 0.205, tiles 0.07 for a truth of rough grout and tiles at 0.13–0.16): the held-out
re-render of that capture went 0.377 → 0.999–1.194 (line / step) and the roughness RMSE rose in
most captures. Half the pixels do not give a ring profile precise enough for a second roughness.

Where the error comes from (``ebr bench flash-fit``, ``docs/bench/flash_fit.md``): on noise-free
renders of the validation captures' own true maps the fitted roughness is off by an RMS of 0.102
against 0.122 from the photos (89 dielectric captures of ``configs/data_real_val.toml``,
``configs/data_real_val2.toml`` and ``configs/data_real_near_far_val.toml``, near pairs; 0.110
and 0.135 on the first two sets' 63, the baseline of the tries below); with the normal map
flattened 0.040, with a constant roughness map 0.091, with both 0.005. The relief is most of it,
and the far pair cancels much of it: on the 22 near-far captures the photos' error is 0.067 from
the near pair and 0.025 with the far pair (noise-free true maps 0.072 → 0.035). These figures
are from before the pixel-median reading; with it the bench reads 0.101 (noise-free) and 0.116
(photos), near-far 0.063 → 0.025 (noise-free 0.072 → 0.035); with the metal rule ("Metal or
dielectric") 0.093 and 0.088, near-far 0.063 → 0.025 (noise-free 0.042 → 0.035: a rock's
noise-free near renders had read as a metal of roughness 0.85).

Tried and dropped (2026-12-06), both on ``configs/data_real_val.toml``: (i) a roughness per
albedo cluster (the pixels split at the median of the fitted diffuse map's log-luminance, each
half ring-fitted alone): the halves' true mean
roughnesses differ by 0.01–0.09, their fitted ones scatter by far more (a rusty painted metal 0.05
and 1.0 for 0.84 and 0.80), roughness map RMSE 0.0857 (one constant) → 0.1465; (ii) a two-lobe
relief reading at RELIEF_GAIN 1.1 (no margin) instead of 2: on the noise-free renders of the true
maps (the first set's 22 dielectric captures) the RMS error rose from 0.044 to 0.061 (the sharp
lobe of a relief-free roughness mixture is not the mean roughness). Measured, to see whether the
relief's slope distribution would be enough: the lobe averaged over 128 normals drawn from the
*true* normal map (azimuths randomised) instead of the flat normal, on both validation sets (63
captures): noise-free renders of the true maps 0.110 → 0.135, photos 0.135 → 0.128. It helps
where the relief is plain bumps (acg_Ground080 0.71 → 0.65 for 0.657, acg_Ground027 0.78 → 0.65
for 0.511, acg_Moss002 0.68 → 0.61 for 0.609) and over-corrects mortar and tile joints (acg_Bricks020
0.54 → 0.46–0.49 for 0.545, a roofing tile set 0.82 → 0.04 for 0.70): where the relief sits with
the albedo, the trimmed ring statistic leaves out its glints, so the distribution alone, even the
true one, does not describe what the rings see. The plain ring mean (``ring_statistic`` ``mean``,
glints kept) reads the noise-free true maps better, 0.110 → 0.083 (0.075 with the true slopes'
lobe), but not the photos: 0.1304 → 0.1258 over all 72 validation captures, all of it one glossy
facade set read as a metal either way (0.78 → 0.66 for 0.057); per capture the error grew in 28
and fell in 12 (median 0.026 → 0.027), so ``trimmed`` stays. Tried and dropped (2026-12-06): a
correction of the fitted roughness learned from the ring profile (ridge regression on the 32 ring
values over their median, the 32 no-flash shares, the fitted roughness, its misfit and relief
flag), trained on noise-free renders (fast renderer, light noise added) of the training material
sets turned, flipped, with their relief scaled and their roughness shifted, five folds of
materials held out. With the roughness spread over 0.1–0.95 and the relief scaled by 0.5–1.5
(1850 renders) the held-out materials' RMS error went 0.183 → 0.156, but on the validation photos
(66 captures read as dielectrics) 0.103 → 0.122 (better in 18, worse in 48: it read them
0.05–0.1 low); close to the materials as they are (roughness ± 0.1, relief × 0.8–1.2; 1200
renders) 0.127 → 0.126 on held-out materials and, on the photos, 0.103 → 0.093 but the median
error 0.030 → 0.043 (better in 23, worse in 43). What one material's relief does to its profile
does not tell another's.

Measured, not adopted (2026-12-07): the diffuse level reads low on relief-heavy sets. Its mean
over the estimate's diffuse map against the truth's was 0.85–0.90 for a thatch, three captures of
a brick set and a rock of ``configs/data_real_val.toml`` and 0.95–1.0 for most flatter ones: a
tilted pixel's co-located shading ``n·l`` is below a flat one's,
and the relief's mean darkening is second order in the slopes, which the shading normals (shrunk,
and blind to relief finer than a pixel) barely see (the truth's mean ``n·l / l_z`` 0.92–0.95 on
those sets, the estimate's normals' 0.97–1.0). Dividing by the truth's own mean ``n_z`` would take
the 22 dielectrics' mean diffuse RMSE 0.04467 → 0.04262 (the estimate's normals: 0.04397; the true
mean level per channel: 0.04147), but a capture does not know its relief, and one factor for all
(× 1.02, the best of 1.02–1.1) moved the set's diffuse RMSE 0.04595 → 0.04525 (all 24) and
0.01661 → 0.01658 on the first 22 captures of ``configs/data_real_val2.toml``.

Tried and dropped (2026-12-07): the network's roughness map as the roughness's pattern around the
fitted value (``r_fit + β (r_net − mean r_net)``), since one value per capture cannot beat the
material's own constant. On ``configs/data_real_val.toml`` (24) the network map's deviations
correlate with the truth's by −0.16 to +0.40 per capture (about 0 for most), and the roughness RMSE
rose with β: 0.0666 / 0.0672 / 0.0688 / 0.0738 at β = 0 / 0.25 / 0.5 / 1 (the truth's own
constant: 0.0571).

Tried and dropped (2026-12-05): denoising the texture pattern with the no-flash shot's. Per band
(the 3 × 3 detail and the rest) the two shots' pattern deviations were combined by their noise
variances and shrunk by signal / (signal + noise), the signal power being the shots' covariance.
On the same 24 validation captures the estimate's diffuse RMSE went 0.04758 → 0.04750 (mean
0.0459 → 0.04588); leaning more on the denoised pattern (network weight 0.3, 0.15 instead of the
default 0.5) made it worse, 0.04934 and 0.05184. The pattern's noise is not what limits the diffuse
map here; the network's share already averages it.

Known bias (measured 2026-12-08): a glossy sample whose roughness varies reads rough once its
highlight is clipped. In the lobe's tail (view angles well past α) the GGX term goes as α², so
the rougher pixels dominate the rings outside the clipped disc and the disc's edge alike; a fit
that sees only the tail reads about (mean r⁴)^¼ rather than the mean. The glazed tile set
acg_Tiles078 of the test split (roughness 0.03–0.12, mean 0.068, (mean r⁴)^¼ 0.084) reads 0.06
from a noise-free render of its true maps with nothing clipped, 0.06 / 0.05 / 0.09 / 0.10 with
50 / 200 / 500 / 1000 pixels clipped, and 0.09 from its photos (about 500 clipped); with flat
normals and a constant roughness the same renders read 0.07–0.08. The saturation term does not help (its
disc edge is in the tail too: at weights 0.05 / 0.2 / 1 the read stays 0.09), nor does predicting
the clipping per colour channel (a pixel clips when any channel does; on flat, constant renders
this took 0.08 back to 0.07, but on the validation photos it moved rough captures whose scattered
bright pixels clip, a wallpaper 0.65 → 0.745–0.825 for 0.657: RMS error of the fitted roughness
0.0460 → 0.0470 and 0.107 → 0.114 on the two real sets). With that tile set's normals tilted to
its highlight (:mod:`.highlight_tilt`), a roughness 0.03 lower would take three of its four test
captures' held-out re-render from 3.83–3.86 to 2.90–3.23. The spread of the roughness is what is
missing; in the tail each pixel's lobe is proportional to its own α², so the ring-wise spread of
the flash-only residual could read it. Tried (2026-12-08) on the validation captures: per pixel of
the tail (unsaturated, not next to a clipped pixel, the fitted lobe over twice the diffuse level
and past twice α from the mirror point) the ratio q = specular residual / fitted lobe is (r(x) /
r)⁴, so the spread of q beyond the photo noise, read as a log-normal, gives the mean roughness
as r · exp(−3σ²/32). Only 2 of the 96 captures of the three validation sets have such a tail
(at 256² a roughness above about 0.15 has none outside the clipped disc): a glossy facade read
0.123 → 0.110 for a truth of 0.057, with the fitted lobe four times the tail's mean (the model
does not hold there), a glazed tile set 0.060 → 0.057 for 0.088. Too few captures to choose
anything, so not adopted; and one glazed tile set's mean would not meet the re-render acceptance
anyway (``docs/models.md``, "What the re-render figure measures": it needs the roughness pattern,
not its mean).

Tried and dropped (2026-12-08), on the metal captures of the validation sets (a polished copper,
acg_Metal034, three times; acg_Metal055A; five procedural metals), judged by ``ebr estimate``'s
maps: (i) the metal hypothesis's saturation term per colour channel (F0's colour read off the
flash-only image's channel shares): no metal moved, and a corrugated steel of the test split read
as a dielectric became a metal of roughness 0.56 (truth 0.40); (ii) the roughness between grid
steps, at the vertex of the parabola through the best step's cost and its neighbours': the
copper read 0.08 / 0.08 / 0.09 → 0.084 / 0.076 / 0.085 (truth 0.074; held-out re-render 10.4 /
10.0 / 14.0 → 12.3 / 8.0 / 12.3), the procedural metals within 0.005 either way, the glazed tile
set above 0.09 → 0.093: the cost between steps is not smooth enough (its saturation terms count
pixels) for the vertex to be a better reading.

Tried and dropped (2026-12-06): searching for the mirror point. A sample whose mean normal is
tilted has its highlight off the frame centre (a glazed tile set of the test split is tilted by
0.3°, 1.6 pixels at 256²), so for lobes sharper than roughness 0.3 the lens and flash position of
the profile was moved by a pattern search over offsets (8 → 0.25 pixels, the centred fit's
roughness ± 0.03), keeping the offset of lowest cost and tilting the normals to match. The cost's
minimum was not the true tilt (a tile set whose tiles differ in roughness, a polished copper):
on three glossy validation captures the held-out re-render went 0.377 → 0.382, 15.1 → 16.7 and
unchanged, the copper's specular RMSE 0.166 → 0.374, and the fit took 3–4 s longer.

Input convention: ``flash`` and ``noflash`` are (H, W, 3) linear photo values (saturating at
``clip``); ``to_radiance`` scales them to the units where the flash has intensity ``intensity``
(the reference exposure, ``docs/conventions.md#exposure``). Cost: one pass over the image per
roughness of the grid (98 by default), about 0.3 s at 256² on two cores (the footprints of the
sharp lobes add about 10 %); the pixel-median reading, where it runs, about 0.9 s more (its ring
medians per roughness and level, reusing the profile's lobe per pixel; 12 validation captures:
0.29–0.30 s without, 1.15–1.34 s with; 1.35–1.46 s before the lobes were shared).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import torch

from ..errors import InputError
from ..geometry import DEFAULT_FLASH_INTENSITY, FAR_DISTANCE, NEAR_DISTANCE, view_directions
from ..imageio import box_mean, resize_area, upsample_bilinear_fast
from ..typedconfig import config, option

__all__ = ["FarPair", "FlashFit", "FlashFitConfig", "fit_flash"]

METAL_MARGIN = 0.5  # the metal hypothesis wins when its cost is below this × the dielectric's
METAL_MAX_ROUGHNESS = 0.75  # ... and its roughness below this (a flatter lobe is a diffuse surface's twin)
NOFLASH_MIN = 2e-3  # no-flash photo mean below which its rings are not read (too dark: noise)
P_RING_MIN = 0.2  # a ring's albedo share read off the no-flash shot is kept within [0.2, 5]
TRIM = 0.1  # the ring statistic (and the "trimmed" level): the mean of the middle 80 % of the values
RELIEF_GAIN = 2.0  # two lobes explain the rings this many times better: the sharper one is the roughness
RELIEF_MARGIN = 1e-4  # ... and by at least this much of the cost (a 1 % rms ring residual: photo noise)
RELIEF_WEIGHTS = (0.25, 0.5, 0.75)  # the sharper lobe's share of F0 in the two-lobe profile
MEDIAN_MIN_ROUGHNESS = 0.1  # a pixel-median reading below this is not used (a lobe ring medians miss)
MEDIAN_LEVELS = (0.6, 1.4, 11)  # the pixel-median reading's level search: × the fit's level, coarse steps
LOBE_SHARE = 0.5  # the "clean" level leaves out the pixels whose fitted lobe exceeds half the level
CLEAN_MIN = 0.1  # ... unless that leaves fewer than 10 % of the pixels (then: the trimmed mean)
LOWS_MIN_SHARE = 0.2  # a low-frequency box with fewer clean pixels than this share keeps the level
NETWORK_WEIGHT_SIZE = 256  # above this side the photo pattern's weight falls as 1 / size
TABLE_SIZE = 1024  # θ samples of the tabulated lobe (linear interpolation per pixel)
FOOTPRINT_ROUGHNESS = 0.3  # below it the lobe is averaged over each pixel's footprint ...
FOOTPRINT_SAMPLES = 3  # ... at FOOTPRINT_SAMPLES² points per pixel
FOOTPRINT_MAX_SIZE = 1024  # ... for the full-size maps only up to this side (module docstring)
FIT_SIZE = 256  # default largest side the profile is read at (FlashFitConfig.fit_size)


@config(error=InputError)
class FlashFitConfig:
    """Options of :func:`fit_flash` (see the module docstring)."""

    f0: float = option(0.04, "specular F0 assumed (a dielectric)", above=0, below=1)
    roughness_min: float = option(0.03, "smallest roughness of the grid", above=0, maximum=1)
    roughness_max: float = option(1.0, "largest roughness of the grid", above=0, maximum=1)
    roughness_steps: int = option(98, "roughness values tried", minimum=2)
    bins: int = option(32, "rings of equal pixel count over cos θ", minimum=4)
    clip: float = option(0.995, "photo value counted as saturated", above=0, maximum=1)
    saturation_weight: float = option(0.05, "weight of the saturation-consistency term", minimum=0)
    fit_size: int = option(
        FIT_SIZE,
        'largest side the profile is fitted at (larger: area-averaged; module docstring, "Fit size")',
        minimum=32,
    )
    network_weight: float = option(
        0.6,
        "weight of the network's diffuse map (scaled to the fitted level) in the diffuse estimate, "
        "photos up to 256² (above: see FlashFitConfig.weight_for)",
        minimum=0,
        maximum=1,
    )

    def weight_for(self, size: int) -> float:
        """The network map's weight for a photo whose larger side is ``size`` pixels:
        ``network_weight`` up to NETWORK_WEIGHT_SIZE, above it the photo's share falls as
        1 / size (its per-pixel noise grows as the pixels shrink; the network's map sharpens),
        as 1 / √size with ``pattern_detail`` (the pattern's noise is already shrunk; module
        docstring, "Detail")."""
        if size <= NETWORK_WEIGHT_SIZE:
            return self.network_weight
        share = NETWORK_WEIGHT_SIZE / size
        return 1.0 - (1.0 - self.network_weight) * (share**0.5 if self.pattern_detail else share)

    pattern: float = option(
        0.125,
        "box of the pattern's local mean (and of its low frequencies), fraction of the image side",
        above=0,
        maximum=1,
    )
    ring_statistic: str = option(
        "trimmed",
        "per-ring statistic of the profile (module docstring)",
        choices=("mean", "median", "trimmed"),
    )
    level_statistic: str = option(
        "clean",
        "statistic of the albedo level over the per-pixel ratios (module docstring)",
        choices=("trimmed", "clean"),
    )
    relief: bool = option(
        True,
        "a two-lobe profile of the near rings that fits RELIEF_GAIN times better than one lobe reads "
        "the relief as the broad lobe and keeps the sharp one's roughness (module docstring)",
    )
    misfit_limit: float = option(
        0.003,
        "ring residual (mean squared, relative to the level) above which the fitted roughness is "
        'replaced by the network\'s map (module docstring, "Misfit"; 1e9: never)',
        minimum=0,
    )
    pattern_lows: bool = option(
        True,
        "the photo pattern's low frequencies, which its local mean divides out, restored per "
        'channel from the flash-only albedo ratio (module docstring, "Low frequencies")',
    )
    pattern_detail: bool = option(
        True,
        "above 256², the photo pattern's detail scaled by its signal share, read off its covariance "
        'with the no-flash shot\'s (module docstring, "Detail")',
    )
    noflash_albedo: bool = option(
        True,
        "near shots alone: read each ring's share of the albedo off the no-flash shot (module docstring)",
    )
    pixel_median: bool = option(
        True,
        "near shots alone: the roughness blends the profile's with a second reading off the ring "
        'medians of each pixel\'s residual (median_weight; module docstring, "The pixel-median reading")',
    )
    median_weight: float = option(
        0.5,
        "the pixel-median reading's share of the roughness where it is used (the profile's: the "
        'rest; module docstring, "The pixel-median reading")',
        minimum=0,
        maximum=1,
    )
    median_alone: float = option(
        0.1,
        "where the pixel-median and profile readings differ by more than this, the median's alone "
        '(module docstring, "The pixel-median reading"; 1: always the blend)',
        minimum=0,
        maximum=1,
    )

    def __post_init__(self):
        from ..typedconfig import check

        check(self)
        if self.roughness_min >= self.roughness_max:
            raise InputError(
                f"FlashFitConfig: roughness_min {self.roughness_min} must be below roughness_max "
                f"{self.roughness_max}"
            )


@dataclass
class FlashFit:
    """What :func:`fit_flash` found.

    ``roughness`` (float), ``f0`` (float), ``level`` (3,) albedo level per channel,
    ``diffuse`` (H, W, 3) in [0, 1], ``grid`` / ``costs`` (R,) the roughness grid and its costs,
    ``specular`` (H, W, 3) the fitted lobe's flash-only radiance.
    """

    roughness: float
    f0: float
    level: np.ndarray
    diffuse: np.ndarray
    grid: np.ndarray
    costs: np.ndarray
    specular: np.ndarray
    metal: bool = False
    specular_rgb: np.ndarray | None = None
    far_pair: bool = False  # the roughness was read off near − far (module docstring, "The far pair")
    relief: dict | None = None  # the two-lobe profile that won (module docstring, "Relief"), or None
    misfit: float | None = None  # the kept profile's ring residual (module docstring, "Misfit")
    pixel_median: dict | None = None  # the pixel-median reading ("The pixel-median reading"), or None
    roughness_map: np.ndarray | None = None  # (H, W): with_network_roughness / with_roughness_pattern
    decision: dict | None = None  # the metal-or-dielectric decision ("Metal or dielectric")
    roughness_pattern: dict | None = None  # set by with_roughness_pattern (estimate/roughness_pattern.py)

    def maps(self, normal: np.ndarray, source: str = "flash fit"):
        """The fitted maps as an :class:`~ebr_mitsuba.svbrdf.SVBRDF` with ``normal`` (H, W, 3):
        the diffuse map, a constant specular F0 and a constant roughness."""
        from ..svbrdf import SVBRDF

        h, w = self.diffuse.shape[:2]
        rgb = self.specular_rgb if self.specular_rgb is not None else np.full(3, self.f0, np.float32)
        specular = np.broadcast_to(np.asarray(rgb, np.float32), (h, w, 3)).copy()
        if self.roughness_map is not None:
            roughness = np.asarray(self.roughness_map, np.float32).reshape(h, w).copy()
        else:
            roughness = np.full((h, w), self.roughness, np.float32)
        return SVBRDF(np.asarray(normal, np.float32), self.diffuse, specular, roughness, source)

    def misfits(self, limit: float) -> bool:
        """Whether the kept lobe profile explains the rings too poorly to be trusted: its ring
        residual ``misfit`` above ``limit`` (module docstring, "Misfit"); never for a metal or a
        roughness read off the far pair (no misfit recorded)."""
        return not self.metal and self.misfit is not None and self.misfit > limit

    def with_network_roughness(self, network_roughness: np.ndarray) -> FlashFit:
        """The fit with the network's (H, W) or (H, W, 1) roughness map in place of the fitted
        constant (module docstring, "Misfit"); diffuse, level and F0 stay the fit's."""
        net = np.asarray(network_roughness, np.float32)
        h, w = self.diffuse.shape[:2]
        if net.size != h * w:
            raise InputError(f"flash fit: the network's roughness map is {net.shape}; expected ({h}, {w})")
        return replace(self, roughness_map=net.reshape(h, w), roughness=float(net.mean()))

    def with_roughness_pattern(self, pattern) -> FlashFit:
        """The fit with the roughness map of ``pattern`` (a
        :class:`~.roughness_pattern.RoughnessPattern`) around the fitted roughness, its texture read
        off this fit's diffuse map; recorded in ``roughness_pattern`` whether applied or not. A fit
        whose roughness is the network's map is returned as it is."""
        if self.roughness_map is not None:
            return self
        record = pattern.to_json()
        if not pattern.applied:
            return replace(self, roughness_pattern=record)
        return replace(
            self,
            roughness_map=pattern.roughness_map(self.roughness, self.diffuse),
            roughness_pattern=record,
        )

    def with_network_diffuse(self, network_diffuse: np.ndarray, weight: float) -> FlashFit:
        """The fit with its diffuse map blended with a network's (H, W, 3) diffuse map, scaled per
        channel to the fitted level: ``(1 − weight) · diffuse + weight · level / mean(net) · net``
        (module docstring); a metal keeps no diffuse."""
        net = np.asarray(network_diffuse, np.float32)
        if net.shape != self.diffuse.shape:
            raise InputError(
                f"flash fit: the network's diffuse map is {net.shape}; expected {self.diffuse.shape}"
            )
        scale = self.level / np.maximum(net.reshape(-1, 3).mean(0), 1e-4)
        scaled = np.clip(net * scale[None, None, :], 0.0, 1.0)
        blend = ((1.0 - weight) * self.diffuse + weight * scaled).astype(np.float32)
        return replace(self, diffuse=blend)

    def with_normals(self, normal: np.ndarray, camera=(0.0, 0.0, NEAR_DISTANCE)) -> FlashFit:
        """The fit with its diffuse map read for ``normal`` (H, W, 3) instead of flat normals: the
        photo's pattern divided by the normals' flash shading relative to a flat sample's,
        ``(n·l) / l_z`` over its mean (the level is kept); a metal keeps no diffuse."""
        n = np.asarray(normal, np.float64)
        if n.shape != self.diffuse.shape:
            raise InputError(f"flash fit: the normal map is {n.shape}; expected {self.diffuse.shape}")
        if self.metal:
            return self
        h, w = n.shape[:2]
        light = view_directions(h, w, camera)  # the flash is at the camera
        shade = np.maximum((n * light).sum(-1), 1e-3) / light[..., 2]
        shade /= shade.mean()
        diffuse = np.clip(self.diffuse / shade[..., None], 0.0, 1.0).astype(np.float32)
        return replace(self, diffuse=diffuse)

    def to_json(self) -> dict:
        rgb = self.specular_rgb if self.specular_rgb is not None else np.full(3, self.f0)
        return {
            "roughness": round(self.roughness, 4),
            "specular": [round(float(x), 4) for x in rgb],
            "diffuse_level": [round(float(x), 4) for x in self.level],
            "metal": self.metal,
            "far_pair": self.far_pair,
            "relief": self.relief,
            "misfit": None if self.misfit is None else float(f"{self.misfit:.3g}"),
            "pixel_median": self.pixel_median,
            "decision": self.decision,
            "roughness_from": (
                "network" if self.roughness_map is not None and self.roughness_pattern is None else "fit"
            ),
            "roughness_pattern": self.roughness_pattern,
        }


@dataclass
class FarPair:
    """The far shots of a near-far capture for :func:`fit_flash` (module docstring, "The far pair").

    ``flash``, ``noflash``: (H, W, 3) linear photo values on the near shots' pixel grid and in their
    units (the frame is the same sample square); ``camera``: the far lens and flash position;
    ``intensity``: the far flash's W/sr in those units (None: the near intensity × (far / near
    distance)², what ``ebr capture`` and ``ebr generate`` use); ``saturated``: (H, W) bool or None
    (``flash ≥ clip`` in any channel)."""

    flash: np.ndarray
    noflash: np.ndarray
    camera: tuple = (0.0, 0.0, FAR_DISTANCE)
    intensity: float | None = None
    saturated: np.ndarray | None = None

    def pixels(self, h: int, w: int, to_radiance: float) -> _FarPixels:
        """Per pixel (flattened) of a pair checked by :func:`_checked_far` (intensity and mask
        resolved): g = flash-only / flat unit-albedo shading, saturated, cos θ."""
        fl = torch.from_numpy(np.asarray(self.flash, np.float64)).reshape(-1, 3)
        nf = torch.from_numpy(np.asarray(self.noflash, np.float64)).reshape(-1, 3)
        sat = torch.from_numpy(np.asarray(self.saturated, bool).reshape(-1))
        cos = torch.from_numpy(view_directions(h, w, self.camera)[..., 2].astype(np.float64)).reshape(-1)
        shade = flat_shading(cos, float(self.camera[2]), float(self.intensity))
        g = ((fl - nf) * to_radiance).mean(-1) / shade  # not clamped: module docstring, "Noise"
        return _FarPixels(g, sat, cos)

    def shrunk(self, f: int) -> FarPair:
        """The pair area-averaged over f × f blocks (a saturated pixel saturates its block)."""
        flash, noflash, saturated = area_shots(f, self.flash, self.noflash, self.saturated)
        return replace(self, flash=flash, noflash=noflash, saturated=saturated)


@dataclass
class _FarPixels:
    g: torch.Tensor
    saturated: torch.Tensor
    cos: torch.Tensor


def _trimmed_mean(x: torch.Tensor, cut: float = TRIM) -> torch.Tensor:
    """Mean of the values between the ``cut`` and ``1 − cut`` quantiles (robust to the residue of
    the highlight and to outliers, unbiased for a symmetric or two-tone texture)."""
    lo, hi = torch.quantile(x, torch.tensor([cut, 1.0 - cut], dtype=x.dtype))
    inside = x[(x >= lo) & (x <= hi)]
    return inside.mean() if inside.numel() else x.mean()


def _clean(ok: torch.Tensor, lobe: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
    """The pixels a level is read on: unsaturated (``ok``) and the fitted ``lobe`` below
    LOBE_SHARE of the (3,) ``level``'s mean (the "clean" statistic, module docstring)."""
    return ok & (lobe < LOBE_SHARE * level.mean())


def _level(ratio: torch.Tensor, ok: torch.Tensor, lobe: torch.Tensor, statistic: str) -> torch.Tensor:
    """(3,) albedo level from the (N, 3) per-pixel ratios ``(F − S) / G``: ``trimmed``, the mean
    of their middle 80 % over the unsaturated pixels ``ok``; ``clean``, the plain mean over the
    unsaturated pixels whose fitted ``lobe`` (N,) stays below LOBE_SHARE of the trimmed level."""
    trimmed = torch.stack([_trimmed_mean(ratio[ok, c]) for c in range(3)]).clamp(1e-4, 1.0)
    if statistic == "trimmed":
        return trimmed
    clean = _clean(ok, lobe, trimmed)
    if int(clean.sum()) < CLEAN_MIN * ok.numel():
        return trimmed
    return ratio[clean].mean(0).clamp(1e-4, 1.0)


class _Profile(NamedTuple):
    """What :func:`_profile` read off the rings."""

    roughness: float  # of lowest cost (the relief's sharp lobe, the mean with the median reading)
    metal: bool  # the metal hypothesis won
    grid: np.ndarray  # (R,) roughness grid
    costs: np.ndarray  # (R,) the kept hypothesis's costs
    far_pair: bool  # the far rings were used
    relief: dict | None
    misfit: float | None  # None: a metal or the far pair
    median: dict | None  # the pixel-median reading's record
    # the metal-or-dielectric decision ("Metal or dielectric"): metal_ratio (best metal cost / best
    # dielectric cost, near rings), metal_level (its F0 level m before the clamp to [1e-4, 1]) and
    # metal_roughness, rounded as estimate.json records them
    decision: dict


def _profile(flash, noflash, saturated, to_radiance, intensity, camera, clip, opts, far=None) -> _Profile:
    """The ring profile's reading (:class:`_Profile`, module docstring); ``saturated`` (H, W)
    bool; ``far``: None or a :class:`FarPair` (its rings are the near rings' pixels, "The far
    pair")."""

    flash = np.asarray(flash, np.float64)
    noflash = np.asarray(noflash, np.float64)
    h, w, _ = flash.shape
    fl = torch.from_numpy(flash).reshape(-1, 3)
    nf = torch.from_numpy(noflash).reshape(-1, 3)
    saturated = torch.from_numpy(np.asarray(saturated, bool).reshape(-1))
    f_only = (fl - nf) * to_radiance  # not clamped per pixel (module docstring, "Noise")
    # co-located flash over the flat sample (z = 0): cos θ = v_z and d = camera_z / cos θ
    v = torch.from_numpy(view_directions(h, w, camera)).reshape(-1, 3)
    cos = v[:, 2].contiguous()
    shade = flat_shading(cos, float(camera[2]), intensity)  # G(x): unit-albedo diffuse, flat normal
    g = f_only.mean(-1) / shade

    # rings of equal pixel count over cos θ; the median of each over unsaturated pixels
    ring = ring_index(cos, opts.bins)
    ring_cos = torch.zeros(opts.bins, dtype=torch.float64)
    ring_med = torch.full((opts.bins,), float("nan"), dtype=torch.float64)
    ring_sat = torch.zeros(opts.bins, dtype=torch.float64)
    ring_floor = torch.zeros(opts.bins, dtype=torch.float64)  # clip level in g units, saturated rings
    clip_g = ((min(clip, 1e30) - nf.mean(-1)) * to_radiance).clamp_min(0.0) / shade
    far_px = None if far is None else far.pixels(h, w, to_radiance)
    excluded = saturated if far_px is None else saturated | far_px.saturated  # the same pixels in both
    kept = ~excluded  # the pixels of each ring's statistic (trimmed: the middle of its g values)
    for k in range(opts.bins):
        inside = ring == k
        ring_cos[k] = cos[inside].mean()
        ring_sat[k] = saturated[inside].double().mean()
        ok = inside & ~excluded
        if int(ok.sum()) > 3:
            if opts.ring_statistic == "median":
                ring_med[k] = g[ok].median()
            elif opts.ring_statistic == "mean":
                ring_med[k] = g[ok].mean()
            else:
                lo_g, hi_g = torch.quantile(g[ok], torch.tensor([TRIM, 1 - TRIM], dtype=g.dtype))
                drop = inside & ((g < lo_g) | (g > hi_g))
                kept &= ~drop
                ring_med[k] = g[inside & kept].mean()
        sat = inside & saturated
        if sat.any():
            ring_floor[k] = clip_g[sat].median()
    usable = ~torch.isnan(ring_med) & (ring_sat < 0.5)
    if int(usable.sum()) < 3:
        raise InputError(
            "fit_flash: fewer than 3 rings of the flash shot are unsaturated; lower the exposure "
            "or the flash power and capture again"
        )
    clipped_rings = ring_sat >= 0.5

    grid = torch.linspace(opts.roughness_min, opts.roughness_max, opts.roughness_steps, dtype=torch.float64)
    ring_v = torch.stack([torch.sqrt(1 - ring_cos**2), torch.zeros_like(ring_cos), ring_cos], -1)

    table = _LobeTable(cos, _footprint_cos(h, w, camera))

    def lobe(vv: torch.Tensor, r: float) -> torch.Tensor:  # π f_s over a set of co-located directions
        return _lobe(vv, r, opts.f0)

    def lobe_pixels(r: float) -> torch.Tensor:
        return table(r, opts.f0)

    n_sat = max(float(saturated.sum()), 10.0)
    photo_scale = shade / to_radiance  # g units → photo units
    nf_grey = nf.mean(-1)
    ring_scale = ring_med[usable].median().clamp_min(1e-6)

    def saturation_cost(g_model: torch.Tensor) -> float:
        predicted = g_model * photo_scale + nf_grey >= clip
        return opts.saturation_weight * float((predicted ^ saturated).sum()) / n_sat

    def floor_cost(ring_model: torch.Tensor, norm: torch.Tensor) -> torch.Tensor:
        if not clipped_rings.any():
            return torch.zeros((), dtype=torch.float64)
        return ((ring_floor[clipped_rings] - ring_model[clipped_rings]) / norm).clamp_min(0.0).pow(2).mean()

    use_mean = opts.ring_statistic != "median"
    ring_ok = torch.where(kept, ring, torch.full_like(ring, opts.bins))  # saturated / trimmed: no ring
    ring_count = torch.bincount(ring_ok, minlength=opts.bins + 1)[: opts.bins].double().clamp_min(1.0)

    def ring_mean(values: torch.Tensor) -> torch.Tensor:  # mean over each ring's unsaturated pixels
        sums = torch.zeros(opts.bins + 1, dtype=torch.float64).index_add_(0, ring_ok, values)
        return sums[: opts.bins] / ring_count

    # the far pair: each ring's mean over the same kept pixels (their albedo mean is the near ring's)
    far_use = torch.zeros(opts.bins, dtype=torch.bool)
    if far_px is not None:
        far_ring = ring_mean(far_px.g)
        far_use = usable & (ring_count >= 4)
        if int(far_use.sum()) < 3:  # too few rings left unsaturated in both shots: the near fit alone
            far_use[:] = False
        far_table = _LobeTable(far_px.cos, _footprint_cos(h, w, far.camera))
    if far_use.any():  # near − far per ring: the albedo cancels, the lobes' difference remains
        observed_diff = ring_med[far_use] - far_ring[far_use]
    use_far = bool(far_use.any())
    # near shots alone: each ring's albedo share p, its no-flash mean over the same kept pixels
    # relative to all rings' ("The no-flash rings"); 1 with the far pair or without a usable shot
    # (the relief check reads the near rings with it either way)
    p_noflash = torch.ones(opts.bins, dtype=torch.float64)
    noflash_read = False
    if opts.noflash_albedo:
        q = ring_mean(nf_grey.clamp_min(0.0))
        q_ok = usable & (ring_count >= 4)
        if int(q_ok.sum()) >= 3 and float(q[q_ok].mean()) > NOFLASH_MIN:
            p_noflash = torch.where(q_ok, q / q[q_ok].mean(), p_noflash).clamp(P_RING_MIN, 1 / P_RING_MIN)
            noflash_read = True
    p_ring = torch.ones(opts.bins, dtype=torch.float64) if use_far else p_noflash

    # dielectric: g = L·p + lobe (F0 = f0); metal: g = m · lobe / f0 (no diffuse, F0 = m); with the far
    # rings, both judged again on near − far
    costs = torch.zeros(len(grid), dtype=torch.float64)
    fits = torch.zeros(len(grid), dtype=torch.float64)  # the ring residual alone (misfit)
    metal_costs = torch.zeros(len(grid), dtype=torch.float64)
    diff_costs = torch.zeros(len(grid), dtype=torch.float64)
    metal_diff_costs = torch.zeros(len(grid), dtype=torch.float64)
    metal_levels = torch.zeros(len(grid), dtype=torch.float64)  # m before its clamp
    s_rings = torch.zeros(len(grid), opts.bins, dtype=torch.float64)
    levels = torch.zeros(len(grid), dtype=torch.float64)  # each single lobe's level
    median_wanted = opts.pixel_median and noflash_read and not use_far  # "The pixel-median reading"
    grid_lobes = []  # each grid roughness's lobe per pixel, for the pixel-median reading
    for i, r in enumerate(grid.tolist()):
        s_pixels = lobe_pixels(r)
        if median_wanted:
            grid_lobes.append(s_pixels)
        s_ring = lobe(ring_v, r)
        if use_mean:  # a lobe sharper than the central ring must show in its mean, as in the data's
            s_ring = torch.where(usable, ring_mean(s_pixels), s_ring)
        s_rings[i] = s_ring
        fit, floor, level = (
            x[0] for x in _ring_costs(s_ring[None], ring_med, p_ring, usable, ring_floor, clipped_rings)
        )
        extra = floor + saturation_cost(level + s_pixels)
        costs[i], fits[i], levels[i] = fit + extra, fit, level
        unit_ring = s_ring / opts.f0
        metal_levels[i] = (ring_med[usable] / unit_ring[usable].clamp_min(1e-12)).median()
        m = metal_levels[i].clamp(1e-4, 1.0)
        metal_extra = floor_cost(m * unit_ring, ring_scale) + saturation_cost(m * s_pixels / opts.f0)
        metal_costs[i] = ((ring_med[usable] - m * unit_ring[usable]) / ring_scale).pow(2).mean() + metal_extra
        if use_far:  # the same hypotheses judged on near − far: the albedo's rings cancel
            s_diff = s_ring[far_use] - ring_mean(far_table(r, opts.f0))[far_use]
            diff_costs[i] = ((observed_diff - s_diff) / level).pow(2).mean() + extra
            unit_diff = s_diff / opts.f0
            md = (observed_diff * unit_diff).sum() / unit_diff.pow(2).sum().clamp_min(1e-30)
            mcd = ((observed_diff - md.clamp(1e-4, 1.0) * unit_diff) / ring_scale).pow(2).mean()
            metal_diff_costs[i] = mcd + metal_extra
    best, best_metal = int(torch.argmin(costs)), int(torch.argmin(metal_costs))
    metal_roughness = float(grid[best_metal])
    # decided on the near rings ("Metal or dielectric")
    metal = (
        bool(metal_costs[best_metal] < METAL_MARGIN * costs[best]) and metal_roughness < METAL_MAX_ROUGHNESS
    )
    decision = {
        "metal_ratio": float(f"{float(metal_costs[best_metal] / costs[best].clamp_min(1e-30)):.3g}"),
        "metal_level": float(f"{float(metal_levels[best_metal]):.3g}"),
        "metal_roughness": round(metal_roughness, 4),
    }
    if use_far:  # the roughness read off near − far (module docstring, "The far pair")
        costs, metal_costs = diff_costs, metal_diff_costs
        best, best_metal = int(torch.argmin(costs)), int(torch.argmin(metal_costs))
    if metal:
        r_metal = float(grid[best_metal])
        return _Profile(r_metal, True, grid.numpy(), metal_costs.numpy(), use_far, None, None, None, decision)
    r_best, relief = float(grid[best]), None
    misfit = None if use_far else float(fits[best])  # near rings only ("Misfit")
    if opts.relief:
        rings = (ring_med, p_noflash, usable, ring_floor, clipped_rings)
        relief = _relief(s_rings, grid, rings)
        if relief is not None:
            r_best = relief["sharp"]
            misfit = None if use_far else relief["fit"]
    median = None
    if median_wanted and relief is None:
        p_pixel = nf_grey / nf_grey[~excluded].mean().clamp_min(1e-12)
        level = float(levels[best])  # the profile's level (p_ring is p_noflash without the far pair)
        r_med = _median_reading(g, p_pixel, ring, ~excluded, opts.bins, grid, grid_lobes, level)
        used = r_med >= MEDIAN_MIN_ROUGHNESS
        median = {"roughness": round(r_med, 4), "profile": round(r_best, 4), "used": used}
        if used:
            share = 1.0 if abs(r_med - r_best) > opts.median_alone else opts.median_weight
            r_best = (1.0 - share) * r_best + share * r_med
    return _Profile(r_best, False, grid.numpy(), costs.numpy(), use_far, relief, misfit, median, decision)


def _median_reading(g, p_pixel, ring, ok, bins: int, grid, lobes, level: float) -> float:
    """The roughness whose lobe leaves the smallest ring medians of the per-pixel residual
    ``g − L·p(x) − lobe(x)`` ("The pixel-median reading"): ``g`` (N,) the flash-only image over
    the flat diffuse shading, ``p_pixel`` (N,) each pixel's albedo share read off the no-flash shot,
    ``ring`` (N,) ring indices, ``ok`` (N,) the pixels read, ``lobes`` the (N,) lobe per pixel of each
    roughness of ``grid`` (the profile's, computed once);
    the level L is searched around the profile's ``level`` (MEDIAN_LEVELS, then finer)."""
    idx = torch.nonzero(ok).squeeze(1)
    order = idx[torch.argsort(ring[idx], stable=True)]
    counts = torch.bincount(ring[order], minlength=bins)
    width = int(counts.max())
    starts = torch.cumsum(counts, 0) - counts
    col = torch.arange(width)
    slot = starts[:, None] + col[None, :]
    valid = col[None, :] < counts[:, None]  # (bins, width): the rings padded to one width
    gather = torch.where(valid, order[slot.clamp(max=len(order) - 1)], torch.zeros_like(slot))
    g_r, p_r = g[gather], p_pixel[gather]
    nan = torch.tensor(float("nan"), dtype=g.dtype)
    lo, hi, steps = MEDIAN_LEVELS
    best_cost, best_r = math.inf, float(grid[0])

    def costs(base: torch.Tensor, levels: torch.Tensor) -> torch.Tensor:  # (n,) mean squared ring median
        res = base[None] - levels[:, None, None] * p_r[None]
        med = torch.where(valid[None], res, nan).nanmedian(dim=-1).values  # (n, bins)
        return (med / level).pow(2).nanmean(dim=-1)

    coarse = torch.linspace(lo * level, hi * level, steps, dtype=g.dtype)
    step = float(coarse[1] - coarse[0])
    for r, lobe in zip(grid.tolist(), lobes):
        base = g_r - lobe[gather]  # (bins, width)
        k = int(torch.argmin(costs(base, coarse)))
        fine = torch.linspace(float(coarse[k]) - step, float(coarse[k]) + step, steps, dtype=g.dtype)
        cost = float(costs(base, fine).min())
        if cost < best_cost:
            best_cost, best_r = cost, float(r)
    return best_r


def _ring_costs(model_lobes, ring_med, p_ring, usable, ring_floor, clipped_rings):
    """(P,) each of the fit term, the clipped rings' floor term and the level of P lobe profiles
    (P, bins) over the rings: the level ``median((g − lobe) / p)`` over the usable rings, the fit
    term the mean squared residual relative to it; the profile's cost is fit + floor (+ the
    saturation term, per pixel, in :func:`_profile`)."""
    g, p, lobes = ring_med[usable], p_ring[usable], model_lobes[:, usable]
    level = ((g - lobes) / p).median(dim=1).values.clamp_min(1e-4)
    fit = ((g - level[:, None] * p - lobes) / level[:, None]).pow(2).mean(1)
    floor = torch.zeros_like(fit)
    if clipped_rings.any():
        model = level[:, None] * p_ring[clipped_rings] + model_lobes[:, clipped_rings]
        floor = ((ring_floor[clipped_rings] - model) / level[:, None]).clamp_min(0.0).pow(2).mean(1)
    return fit, floor, level


def _relief(s_rings, grid, rings) -> dict | None:
    """The two-lobe profile (module docstring, "Relief"). ``s_rings`` (R, bins) each grid
    roughness's ring lobe, ``rings`` the ring data of :func:`_ring_costs`. Every pair of grid
    roughnesses is tried, the sharper lobe with each share of RELIEF_WEIGHTS, and judged on the
    rings as every single lobe is (the saturation term is left out: it differs little between
    profiles and would drown the rings' difference). Returns ``sharp``, ``broad``, ``weight``,
    ``gain``, ``single_cost``, ``fit`` (the pair's ring residual) when the best pair's cost is
    RELIEF_GAIN times below the best single lobe's and RELIEF_MARGIN below it, else None."""
    fit, floor, _ = _ring_costs(s_rings, *rings)
    single = float((fit + floor).min())
    i, j = torch.triu_indices(len(grid), len(grid), 1)
    weights = torch.tensor(RELIEF_WEIGHTS, dtype=torch.float64)
    mixed = weights[:, None, None] * s_rings[i][None] + (1 - weights[:, None, None]) * s_rings[j][None]
    fit, floor, _ = _ring_costs(mixed.reshape(-1, s_rings.shape[1]), *rings)
    costs = fit + floor
    k = int(torch.argmin(costs))
    pair_fit = float(fit[k])
    gain = single / max(float(costs[k]), 1e-30)
    if gain < RELIEF_GAIN or single - float(costs[k]) < RELIEF_MARGIN:
        return None
    w, pair = divmod(k, len(i))
    return {
        "sharp": round(float(grid[i[pair]]), 4),
        "broad": round(float(grid[j[pair]]), 4),
        "weight": float(weights[w]),
        "gain": round(gain, 2),
        "single_cost": float(f"{single:.3g}"),
        "fit": float(f"{pair_fit:.3g}"),
    }


def _grey_pattern(img: np.ndarray, radius: int) -> np.ndarray:
    """(H, W) float32: ``img`` (H, W, 3) over its local mean (a box of radius ``radius``), averaged
    over the channels."""
    pattern = np.zeros(img.shape[:2], np.float32)
    for c in range(3):  # one channel at a time: box_mean's float64 sums are the peak memory
        pattern += (img[..., c] / np.maximum(box_mean(img[..., c], radius), 1e-8)).astype(np.float32) / 3
    return pattern


def _low_shape(ratio: np.ndarray, clean: np.ndarray, radius: int) -> np.ndarray:
    """(H, W, 3) float32, mean 1 per channel: the albedo ratio ``(F − S) / G`` (H, W, 3) averaged
    over a box of ``radius`` around every pixel, counting only the ``clean`` (H, W) pixels (the
    level's: unsaturated, the fitted lobe below half the level); where a box holds under
    LOWS_MIN_SHARE of them, 1 (module docstring, "Low frequencies")."""
    weight = box_mean(clean.astype(np.float64), radius)
    enough = weight >= LOWS_MIN_SHARE
    shape = np.ones(ratio.shape, np.float32)
    if not enough.any():
        return shape
    for c in range(3):  # one channel at a time: box_mean's float64 sums are the peak memory
        low = box_mean(np.where(clean, ratio[..., c], 0.0).astype(np.float64), radius) / np.maximum(
            weight, 1e-12
        )
        mean = float(low[enough].mean())
        if mean > 0:
            shape[..., c] = np.where(enough, np.maximum(low, 0.0) / mean, 1.0)
    return shape


def _detail_shrunk(pattern: np.ndarray, other: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """``pattern`` (H, W) with its detail above NETWORK_WEIGHT_SIZE² scaled by its signal share
    (module docstring, "Detail"): ``low + g · (pattern − low)``, ``low`` the pattern area-averaged
    to that size and upsampled, ``g = cov(d, d') / var(d)`` clipped to [0, 1] over the unsaturated
    pixels ``ok`` (H, W), ``d'`` the same detail of ``other``, the no-flash shot's pattern."""
    h, w = pattern.shape
    f = NETWORK_WEIGHT_SIZE / max(h, w)
    size = (max(1, round(h * f)), max(1, round(w * f)))

    def low_of(x: np.ndarray) -> np.ndarray:
        return upsample_bilinear_fast(resize_area(x, size), (h, w))

    low = low_of(pattern)
    d = (pattern - low)[ok].astype(np.float64)
    d_other = (other - low_of(other))[ok].astype(np.float64)
    gain = float(np.clip(np.mean(d * d_other) / max(float(np.mean(d * d)), 1e-12), 0.0, 1.0))
    return low + np.float32(gain) * (pattern - low)


def _lobe(v: torch.Tensor, r: float, f0: float) -> torch.Tensor:
    """π f_s of the flat sample seen and lit along each co-located direction of ``v`` (N, 3),
    float64 (F₀ ``f0``, roughness ``r``)."""
    from ..nets import torch_brdf as tb

    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(v)
    spec = torch.full_like(v, f0)
    rough = torch.full(v.shape[:-1], r, dtype=torch.float64)
    return math.pi * tb.specular_term(n, v, v, spec, rough)[..., 0]


class _LobeTable:
    """The lobe at each pixel: it depends on the view angle θ alone, so it is tabulated from θ = 0
    to the largest θ given (TABLE_SIZE samples uniform in θ, float64) and interpolated linearly; the
    interpolation weights are computed once, a call per (roughness, F₀) evaluates the table only.
    Uniform in θ, not in cos θ: the core of a sharp lobe (roughness 0.074: α = 0.0055 rad) lies
    within 1 − cos θ < 2e-5, inside the first interval of a table uniform in cos θ.

    ``footprint``: (N, S) cos θ of S points spread over each pixel; given, roughnesses below
    FOOTPRINT_ROUGHNESS are averaged over them (the photo is the lobe integrated over the pixel, a
    box filter), the others read at ``cos`` (the pixel centre). Values in ``cos``'s dtype."""

    def __init__(self, cos: torch.Tensor, footprint: torch.Tensor | None = None):
        self.dtype = cos.dtype
        theta = torch.acos(cos.double().clamp(-1.0, 1.0))
        sub = None if footprint is None else torch.acos(footprint.double().clamp(-1.0, 1.0))
        top = max(float(theta.max()), 0.0 if sub is None else float(sub.max()))
        self.dt = max(top, 1e-9) / (TABLE_SIZE - 1)  # from θ = 0: the peak is a node
        t = torch.arange(TABLE_SIZE, dtype=torch.float64) * self.dt
        self.v = torch.stack([torch.sin(t), torch.zeros_like(t), torch.cos(t)], -1)
        self.centre = self._weights(theta)
        self.footprint = None if sub is None else self._weights(sub)

    def _weights(self, theta: torch.Tensor):
        pos = theta / self.dt
        lo = pos.floor().long().clamp(0, TABLE_SIZE - 2)
        return lo, (pos - lo).clamp(0.0, 1.0)

    def __call__(self, r: float, f0: float) -> torch.Tensor:
        t = _lobe(self.v, r, f0)
        lo, frac = self.footprint if self.footprint is not None and r < FOOTPRINT_ROUGHNESS else self.centre
        out = t[lo] * (1 - frac) + t[lo + 1] * frac
        if out.ndim == 2:
            out = out.mean(-1)
        return out.to(self.dtype)


def _footprint_cos(h: int, w: int, camera, samples: int = FOOTPRINT_SAMPLES) -> torch.Tensor:
    """(H·W, samples²) cos θ of a samples × samples grid of points over each pixel (the pixel
    centres of the grid ``samples`` times finer, grouped by pixel)."""
    s = samples
    cos = view_directions(h * s, w * s, camera)[..., 2].reshape(h, s, w, s).transpose(0, 2, 1, 3)
    return torch.from_numpy(np.ascontiguousarray(cos).reshape(h * w, s * s))


def flat_shading(cos, camera_z: float, intensity: float):
    """G(x) = intensity · cos θ / (π d²), d = camera_z / cos θ: the flash's radiance off a flat
    unit-albedo diffuse sample seen from the flash (``cos`` a numpy array or a torch tensor)."""
    return intensity * cos / (math.pi * (camera_z / cos) ** 2)


def ring_index(cos: torch.Tensor, bins: int) -> torch.Tensor:
    """Each pixel's ring (N,) int64: ``bins`` rings of equal pixel count over ``cos`` (N,) float64."""
    edges = torch.quantile(cos, torch.linspace(0, 1, bins + 1, dtype=torch.float64))
    return torch.bucketize(cos, edges[1:-1])


def shrink_factor(h: int, w: int, size: int) -> int:
    """The block size f that brings the larger of ``h``, ``w`` to at most ``size`` (1: none)."""
    return -(-max(h, w) // size)


def area_shots(f: int, flash: np.ndarray, noflash: np.ndarray, saturated: np.ndarray):
    """``flash``, ``noflash`` and the (H, W) bool ``saturated`` averaged over f × f blocks (a
    saturated pixel saturates its block)."""
    return _area(flash, f), _area(noflash, f), area_mask(saturated, f)


def area_mask(mask: np.ndarray, f: int) -> np.ndarray:
    """An (H, W) bool ``mask`` on the grid of :func:`area_shots`: a block is set when any of its
    f × f pixels is."""
    return _area(np.asarray(mask, np.float32), f) > 0


def _area(a: np.ndarray, f: int) -> np.ndarray:
    """``a`` (H, W[, C]) centre-cropped to a multiple of ``f`` and averaged over f × f blocks."""
    h, w = (a.shape[0] // f) * f, (a.shape[1] // f) * f
    y0, x0 = (a.shape[0] - h) // 2, (a.shape[1] - w) // 2
    a = a[y0 : y0 + h, x0 : x0 + w]
    return a.reshape(h // f, f, w // f, f, *a.shape[2:]).mean(axis=(1, 3))


def _checked_far(far: FarPair, shape, intensity: float, camera, clip: float) -> FarPair:
    """``far`` with its photos as float32 (H, W, 3) of ``shape``, its intensity resolved and its
    saturation mask made (``flash ≥ clip``) when not given."""
    fl = np.asarray(far.flash, np.float32)
    nf = np.asarray(far.noflash, np.float32)
    if fl.shape != tuple(shape) or nf.shape != tuple(shape):
        raise InputError(
            f"fit_flash: the far shots are {fl.shape} and {nf.shape}; expected the near shots' {tuple(shape)}"
        )
    value = far.intensity
    if value is None:
        value = intensity * (float(far.camera[2]) / float(camera[2])) ** 2
    if not value > 0:
        raise InputError(f"fit_flash: the far flash intensity ({value}) must be > 0")
    sat = (fl >= clip).any(-1) if far.saturated is None else np.asarray(far.saturated, bool)
    if sat.size != shape[0] * shape[1]:
        raise InputError(
            f"fit_flash: the far saturation mask has {sat.size} pixels; expected {shape[0]}x{shape[1]}"
        )
    sat = sat.reshape(shape[:2])
    return replace(far, flash=fl, noflash=nf, intensity=float(value), saturated=sat)


def fit_flash(
    flash: np.ndarray,
    noflash: np.ndarray,
    *,
    to_radiance: float = 1.0,
    intensity: float = DEFAULT_FLASH_INTENSITY,
    camera=(0.0, 0.0, NEAR_DISTANCE),
    saturated: np.ndarray | None = None,
    clip_level: float | None = None,
    options: FlashFitConfig | None = None,
    far: FarPair | None = None,
) -> FlashFit:
    """Fit roughness, albedo level and diffuse pattern to a flash / no-flash pair (module docstring).

    ``flash``, ``noflash``: (H, W, 3) linear photo values; ``to_radiance``: their scale to the
    flash's units; ``intensity``: the flash's W/sr; ``camera``: the lens and flash position;
    ``saturated``: (H, W) bool mask of clipped pixels (None: ``flash ≥ clip_level`` in any
    channel); ``clip_level``: the photo value that saturates (None: ``options.clip``; ``inf``:
    nothing saturates, the saturation terms vanish); ``far``: the far shots of a near-far capture
    (module docstring, "The far pair"). Photos larger than ``options.fit_size`` are fitted
    (roughness, metal or not) on an area-averaged copy; the maps are made at full size.
    """
    opts = options or FlashFitConfig()
    flash = np.asarray(flash, np.float32)
    noflash = np.asarray(noflash, np.float32)
    if flash.ndim != 3 or flash.shape[-1] != 3 or noflash.shape != flash.shape:
        raise InputError(
            f"fit_flash: flash {flash.shape} and noflash {noflash.shape} must be the same (H, W, 3)"
        )
    if not to_radiance > 0 or not intensity > 0:
        raise InputError(f"fit_flash: to_radiance ({to_radiance}) and intensity ({intensity}) must be > 0")
    h, w, _ = flash.shape
    clip = opts.clip if clip_level is None else float(clip_level)
    if saturated is None:
        saturated = (flash >= clip).any(-1)
    else:
        saturated = np.asarray(saturated, bool)
        if saturated.size != h * w:
            raise InputError(f"fit_flash: the saturation mask has {saturated.size} pixels; expected {h}x{w}")
        saturated = saturated.reshape(h, w)
    if far is not None:
        far = _checked_far(far, flash.shape, intensity, camera, clip)
    f = shrink_factor(h, w, opts.fit_size)
    if f > 1:
        small = area_shots(f, flash, noflash, saturated)
        far = None if far is None else far.shrunk(f)
    else:
        small = (flash, noflash, saturated)
    prof = _profile(*small, to_radiance, intensity, camera, clip, opts, far)
    r_fit, metal, grid, costs, used_far = prof.roughness, prof.metal, prof.grid, prof.costs, prof.far_pair
    relief, misfit, median, decision = prof.relief, prof.misfit, prof.median, prof.decision

    # the maps at full size (float32)
    fl = torch.from_numpy(flash).reshape(-1, 3)
    nf = torch.from_numpy(noflash).reshape(-1, 3)
    ok = ~torch.from_numpy(saturated.reshape(-1))
    signed = (fl - nf) * to_radiance  # the flash-only image, unclamped (module docstring, "Noise")
    f_only = signed.clamp_min(0.0)  # clamped for the diffuse maps
    cos = torch.from_numpy(view_directions(h, w, camera)[..., 2].astype(np.float32)).reshape(-1)
    shade = flat_shading(cos, float(camera[2]), intensity)  # G(x), unit albedo, flat
    footprint = r_fit < FOOTPRINT_ROUGHNESS and max(h, w) <= FOOTPRINT_MAX_SIZE  # "The lobe per pixel"
    lobe = _LobeTable(cos, _footprint_cos(h, w, camera) if footprint else None)
    if metal:
        unit_pix = lobe(r_fit, 1.0)  # g units per unit F0
        # F0 per channel: least squares of the unclamped image on the unit lobe, unsaturated pixels
        u = (shade * unit_pix)[ok]
        f0_rgb = ((signed[ok] * u[:, None]).sum(0) / (u * u).sum().clamp_min(1e-30)).clamp(1e-3, 1.0)
        spec_radiance = (unit_pix * shade)[:, None] * f0_rgb[None, :]
        return FlashFit(
            roughness=r_fit,
            f0=float(f0_rgb.mean()),
            level=np.zeros(3, np.float32),
            diffuse=np.zeros((h, w, 3), np.float32),
            grid=grid,
            costs=costs,
            specular=spec_radiance.reshape(h, w, 3).numpy(),
            metal=True,
            specular_rgb=f0_rgb.numpy().astype(np.float32),
            far_pair=used_far,
            decision=decision,
        )
    del signed
    s_pix = lobe(r_fit, opts.f0)  # g units
    spec_radiance = s_pix[:, None] * shade[:, None]  # flash-only radiance of the lobe (grey F0)
    ratio = (f_only - spec_radiance) / shade[:, None]
    level_rgb = _level(ratio, ok, s_pix, opts.level_statistic)
    radius = max(3, int(round(opts.pattern * max(h, w))) | 1) // 2  # an odd box of ≈ pattern × the side
    lows = np.ones((h, w, 1), np.float32)
    if opts.pattern_lows:  # module docstring, "Low frequencies"
        clean = _clean(ok, s_pix, level_rgb)
        lows = _low_shape(ratio.reshape(h, w, 3).numpy(), clean.reshape(h, w).numpy(), radius)
    del ratio, f_only
    # the texture pattern: the flash photo minus the lobe, over its local mean (grey)
    img = (fl - spec_radiance / to_radiance).clamp_min(0.0).reshape(h, w, 3).numpy()
    pattern = _grey_pattern(img, radius)
    if max(h, w) > NETWORK_WEIGHT_SIZE and opts.pattern_detail:  # module docstring, "Detail"
        pattern = _detail_shrunk(pattern, _grey_pattern(noflash, radius), ~saturated)
    diffuse = np.clip(level_rgb.numpy()[None, None, :] * lows * pattern[..., None], 0.0, 1.0)
    return FlashFit(
        roughness=r_fit,
        f0=opts.f0,
        level=level_rgb.numpy().astype(np.float32),
        diffuse=diffuse.astype(np.float32),
        grid=grid,
        costs=costs,
        specular=spec_radiance.expand(-1, 3).reshape(h, w, 3).numpy(),
        metal=False,
        specular_rgb=np.full(3, opts.f0, np.float32),
        far_pair=used_far,
        relief=relief,
        misfit=misfit,
        pixel_median=median,
        decision=decision,
    )
