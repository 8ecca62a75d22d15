using System;
using System.Collections.Generic;
using System.Globalization;
using System.Threading.Tasks;
using GLTFast;
using UnityEngine;

namespace Vista.Client.Unity
{
    /// <summary>
    /// Shows an inspection's scene.glb: imports it with glTFast under <see cref="SceneRoot"/>,
    /// finds the defect nodes (<c>defect-&lt;id&gt;</c>, made pickable) and the image-marker
    /// anchors (<c>marker-&lt;name&gt;</c>), and reads the nodes' glTF <c>extras</c> from the file's
    /// JSON chunk with the protocol core's <see cref="GlbScene"/> (the same reader the smoke test
    /// checks against a live server; no Newtonsoft add-on needed). A new scene replaces the old
    /// one only once it imported.
    /// </summary>
    public sealed class SceneLoader : MonoBehaviour
    {
        const float HighlightScale = 1.6f;

        [Tooltip("The scene's root: MarkerAlignment moves it; keep its scale 1 (glTF is in metres).")]
        [SerializeField] Transform sceneRoot;

        readonly Dictionary<long, GameObject> defectObjects = new Dictionary<long, GameObject>();
        readonly Dictionary<string, Transform> markerAnchors = new Dictionary<string, Transform>();
        GltfImport import;
        GameObject instance;
        GameObject highlighted;
        Vector3 highlightedScale;

        /// <summary>Raised after a scene was imported and indexed.</summary>
        public event Action Loaded;

        /// <summary>The transform the scene is instantiated under (this one if none is set).</summary>
        public Transform SceneRoot => sceneRoot != null ? sceneRoot : transform;

        /// <summary>The loaded file's JSON (defect extras, anchor poses, asset extras), or null.</summary>
        public GlbScene Document { get; private set; }

        /// <summary>The GameObject of each defect node, by defect id.</summary>
        public IReadOnlyDictionary<long, GameObject> DefectObjects => defectObjects;

        /// <summary>The anchor Transform of each image marker, by marker name.</summary>
        public IReadOnlyDictionary<string, Transform> MarkerAnchors => markerAnchors;

        /// <summary>Imports a scene.glb and shows it in place of the current one; false (and the
        /// current scene kept) when glTFast cannot import it.</summary>
        public async Task<bool> LoadAsync(byte[] glb)
        {
            GlbScene document = GlbScene.Parse(glb);
            var next = new GltfImport();
            if (!await next.LoadGltfBinary(glb))
            {
                next.Dispose();
                Debug.LogError("vista: glTFast could not import scene.glb");
                return false;
            }
            var holder = new GameObject("vista-scene");
            holder.transform.SetParent(SceneRoot, false);
            if (!await next.InstantiateMainSceneAsync(holder.transform))
            {
                Destroy(holder);
                next.Dispose();
                Debug.LogError("vista: glTFast could not instantiate scene.glb");
                return false;
            }
            Unload();
            import = next;
            instance = holder;
            Document = document;
            Index(holder.transform, document);
            Loaded?.Invoke();
            return true;
        }

        /// <summary>Enlarges one defect's marker (and restores the one enlarged before); null
        /// clears the highlight.</summary>
        public void Highlight(long? defectId)
        {
            if (highlighted != null)
            {
                highlighted.transform.localScale = highlightedScale;
                highlighted = null;
            }
            if (defectId.HasValue && defectObjects.TryGetValue(defectId.Value, out GameObject target))
            {
                highlighted = target;
                highlightedScale = target.transform.localScale;
                target.transform.localScale = highlightedScale * HighlightScale;
            }
        }

        /// <summary>Finds the GameObjects of the file's defect and anchor nodes by name (only
        /// names the file's node list has: glTFast may add objects of its own).</summary>
        void Index(Transform root, GlbScene document)
        {
            foreach (Transform node in root.GetComponentsInChildren<Transform>(true))
            {
                string name = node.name;
                if (name.StartsWith(GlbScene.DefectPrefix, StringComparison.Ordinal)
                    && long.TryParse(name.Substring(GlbScene.DefectPrefix.Length), NumberStyles.None, CultureInfo.InvariantCulture, out long defectId)
                    && document.DefectExtras.ContainsKey(defectId))
                {
                    defectObjects[defectId] = node.gameObject;
                    node.gameObject.AddComponent<DefectHandle>().DefectId = defectId;
                    if (node.GetComponent<Collider>() == null)
                    {
                        node.gameObject.AddComponent<SphereCollider>();
                    }
                }
                else if (name.StartsWith(GlbScene.MarkerPrefix, StringComparison.Ordinal)
                    && document.MarkerAnchors.ContainsKey(name.Substring(GlbScene.MarkerPrefix.Length)))
                {
                    markerAnchors[name.Substring(GlbScene.MarkerPrefix.Length)] = node;
                }
            }
        }

        void Unload()
        {
            highlighted = null;
            defectObjects.Clear();
            markerAnchors.Clear();
            Document = null;
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
