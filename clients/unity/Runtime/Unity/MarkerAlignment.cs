using System;
using UnityEngine;
using CorePose = Vista.Client.Pose;

namespace Vista.Client.Unity
{
    /// <summary>
    /// Puts the scene where the real aircraft is: when the AR library sees a printed image
    /// marker, call <see cref="OnMarkerSeen"/> with the marker's name and its pose in the
    /// headset's world (e.g. from Vuforia's <c>ObserverBehaviour.OnTargetStatusChanged</c>, with
    /// the observer's <c>TargetName</c> and transform, while the status is TRACKED). The scene root
    /// is moved so that the anchor node <c>marker-&lt;name&gt;</c> lands on the seen pose, with the
    /// protocol core's <see cref="Alignment.WorldFromScene"/>.
    /// <para>
    /// Both poses are taken in Unity's frame, after glTFast's import: the anchor's Transform
    /// then has +X to the image's left, +Y out of the image and +Z to the image's bottom (the
    /// glTF axes of <see cref="Alignment"/>, mirrored in x as glTFast converts to Unity).
    /// The seen pose must be of a frame with those axes; <see cref="trackerToAnchor"/> turns
    /// the tracker's own target frame into it. A target frame with +X to the image's right,
    /// +Y out of the image and +Z to its top needs (0, 180, 0). Check it once on the device
    /// with the printed marker: the anchor's axes must match the image's.
    /// </para>
    /// </summary>
    public sealed class MarkerAlignment : MonoBehaviour
    {
        [SerializeField] SceneLoader sceneLoader;

        [Tooltip("Euler angles (degrees) from the AR library's image-target frame to the anchor's frame (+X image left, +Y out of the image, +Z image bottom).")]
        [SerializeField] Vector3 trackerToAnchor = new Vector3(0f, 180f, 0f);

        /// <summary>Raised with the marker's name after the scene was aligned on it.</summary>
        public event Action<string> Aligned;

        /// <summary>The marker the scene was last aligned on, or null.</summary>
        public string LastMarker { get; private set; }

        /// <summary>The AR library sees the image marker <paramref name="markerName"/> at
        /// <paramref name="worldPose"/> (Unity world, metres): align the scene on it.</summary>
        public void OnMarkerSeen(string markerName, UnityEngine.Pose worldPose)
        {
            if (!sceneLoader.MarkerAnchors.TryGetValue(markerName, out Transform anchor))
            {
                Debug.LogWarning($"vista: the scene has no anchor marker-{markerName}; is it one of the inspection's markers?");
                return;
            }
            Transform root = sceneLoader.SceneRoot;
            CorePose sceneFromMarker = ToCore(
                root.InverseTransformPoint(anchor.position),
                Quaternion.Inverse(root.rotation) * anchor.rotation);
            CorePose worldFromMarker = ToCore(worldPose.position, worldPose.rotation * Quaternion.Euler(trackerToAnchor));
            CorePose worldFromScene = CorePose.FromMatrix(Alignment.WorldFromScene(worldFromMarker, sceneFromMarker));
            root.SetPositionAndRotation(
                new Vector3((float)worldFromScene.X, (float)worldFromScene.Y, (float)worldFromScene.Z),
                new Quaternion((float)worldFromScene.Qx, (float)worldFromScene.Qy, (float)worldFromScene.Qz, (float)worldFromScene.Qw));
            LastMarker = markerName;
            Aligned?.Invoke(markerName);
        }

        static CorePose ToCore(Vector3 position, Quaternion rotation)
        {
            return new CorePose(position.x, position.y, position.z, rotation.x, rotation.y, rotation.z, rotation.w);
        }
    }
}
