using System;
using System.Threading.Tasks;
using GLTFast;
using UnityEngine;

namespace Vista.Client.Unity
{
    /// <summary>
    /// Shows a job's scene.glb (a trajectory, depth clouds, a track through a LiDAR drive —
    /// what a sync page lists in <c>JobScenes</c>): imports it with glTFast and its animation
    /// <c>frames</c> for the legacy animation system, and plays that in a loop (each scan shown
    /// for its frame, the tracked box moving one key a frame). The root node's extras — the
    /// job's kind and the run's figures — are read with the protocol core's
    /// <see cref="JobScene"/>. A new scene replaces the old one only once it imported.
    /// </summary>
    public sealed class JobSceneLoader : MonoBehaviour
    {
        [Tooltip("Where job scenes appear (glTF is in metres: keep its scale 1).")]
        [SerializeField] Transform sceneRoot;

        [Tooltip("Play a drive's frames in a loop as soon as it is loaded.")]
        [SerializeField] bool playOnLoad = true;

        GltfImport import;
        GameObject instance;

        /// <summary>Raised after a job scene was imported.</summary>
        public event Action Loaded;

        /// <summary>The transform job scenes are instantiated under (this one if none is set).</summary>
        public Transform SceneRoot => sceneRoot != null ? sceneRoot : transform;

        /// <summary>The loaded file's root extras, frame length and animation, or null.</summary>
        public JobScene Document { get; private set; }

        /// <summary>The drive's frames as a legacy animation (null: a scene without frames).</summary>
        public Animation Frames { get; private set; }

        /// <summary>Imports a job's scene.glb and shows it in place of the current one; false
        /// (and the current one kept) when glTFast cannot import it.</summary>
        public async Task<bool> LoadAsync(byte[] glb)
        {
            JobScene document = JobScene.Parse(glb);
            var next = new GltfImport();
            var settings = new ImportSettings { AnimationMethod = AnimationMethod.Legacy };
            if (!await next.LoadGltfBinary(glb, null, settings))
            {
                next.Dispose();
                Debug.LogError("vista: glTFast could not import the job's scene.glb");
                return false;
            }
            var holder = new GameObject("vista-job-scene");
            holder.transform.SetParent(SceneRoot, false);
            if (!await next.InstantiateMainSceneAsync(holder.transform))
            {
                Destroy(holder);
                next.Dispose();
                Debug.LogError("vista: glTFast could not instantiate the job's scene.glb");
                return false;
            }
            Unload();
            import = next;
            instance = holder;
            Document = document;
            Frames = holder.GetComponentInChildren<Animation>();
            if (Frames != null && Frames.clip != null)
            {
                Frames.wrapMode = WrapMode.Loop;
                if (playOnLoad)
                {
                    Frames.Play();
                }
            }
            Loaded?.Invoke();
            return true;
        }

        /// <summary>Shows frame <paramref name="index"/> of a drive (paused there).</summary>
        public void ShowFrame(int index)
        {
            if (Frames == null || Frames.clip == null || Document == null)
            {
                return;
            }
            AnimationState state = Frames[Frames.clip.name];
            state.enabled = true;
            state.speed = 0;
            state.time = (float)(Math.Max(0, index) * Document.FrameSeconds);
            Frames.Sample();
        }

        void Unload()
        {
            Document = null;
            Frames = null;
            if (instance != null)
            {
                Destroy(instance);
                instance = null;
            }
            import?.Dispose();
            import = null;
        }

        void OnDestroy()
        {
            Unload();
        }
    }
}
